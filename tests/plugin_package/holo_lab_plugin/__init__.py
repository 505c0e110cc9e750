"""A lab's plug-ins for holocore (a demonstration): one module each, declared by entry point in pyproject.toml."""
