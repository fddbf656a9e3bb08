"""`python -m bgc.cli ARGS`: the command line without the run-record replay (bgc.cli.launch)."""
from bgc.cli.commands import main
from bgc.cli.launch import exit_now

exit_now(main)
