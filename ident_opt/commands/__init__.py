"""One module per `ident-opt` subcommand: `add_arguments(parser)` and `run(args) -> exit status`."""
