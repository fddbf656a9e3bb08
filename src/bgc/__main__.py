from bgc.cli.launch import main

main()
