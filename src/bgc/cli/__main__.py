"""`python -m bgc.cli ARGS`: the command line without the run-record replay (bgc.cli.launch)."""
from bgc.cli.commands import main

main()
