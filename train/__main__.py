from ocalib.train.cli import main

main()
