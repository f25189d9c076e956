"""One module per CLI verb.  Each has ``add_parser(subparsers)`` and ``run(args) -> int``.

The CLI stays thin: a command parses, assembles the pieces and runs them.
"""
