"""Phase-only encoding (docs/design.md §6): the entry point (`encoder`), RESULT -> STACK in bounded memory (`stream`,
`block`), Adam on the phase (`sgd`) with its propagation operator (`operator`), shared pieces (`core`), 8-bit frames
and STACK writing (`output`)."""
