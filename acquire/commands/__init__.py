"""The ``acquire`` command's front-ends: options, entry point, and one module per subcommand."""
