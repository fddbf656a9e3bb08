from bgc.cli.launch import run

run()
