"""The ``identify`` command's front-ends: options, entry point, and one module per subcommand (the edge where files are
read)."""
