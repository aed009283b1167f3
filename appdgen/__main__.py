"""`python -m appdgen …` runs the command line (the same as the `appdgen` command)."""
from appdgen.cli import main

main()
