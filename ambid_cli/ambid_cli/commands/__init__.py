"""One module per ambid subcommand: HELP, add_arguments(parser), run(args) -> exit code."""
