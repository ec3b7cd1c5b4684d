"""One module per ``companion`` subcommand; each defines ``register(subparsers)``."""
