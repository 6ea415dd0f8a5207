from tpos_cli.cli import main

main()
