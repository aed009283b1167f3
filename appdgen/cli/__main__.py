"""`python -m appdgen.cli …` runs the command line."""
from appdgen.cli import main

main()
