"""The package's version, its one source: ``pyproject.toml`` reads it from here (hatch's
``[tool.hatch.version]``), ``wmr.__version__`` is it, and every layer that stamps it (an FMU's
build digest, a log's ``library`` field, a scenario file's header) imports it from here, below
them all, not from the package's top (``docs/architecture.md``: no import runs back up)."""

__version__ = "0.1.0"
