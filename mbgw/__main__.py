from mbgw.cli import main

main()
