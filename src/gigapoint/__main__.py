"""`python -m gigapoint ...`: the command line, as the `gigapoint` script runs it."""

from .cli import run

run()
