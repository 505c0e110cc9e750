"""Scenes in (docs/design.md §1, first stage): the bundle check (`bundle`, `filekinds`), loading through it (`load`),
errors that name the user's file (`errors`), and the scenes the project writes itself (`demo`, `paper`)."""
