from msleak.cli import main

main()
