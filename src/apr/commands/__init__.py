"""The ``apr`` command's subcommands, each a typed argument dataclass and a ``run`` function."""
