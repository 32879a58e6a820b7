#!/usr/bin/env python3
"""Run the softgen command line from a checkout: ``python cli.py list``."""
import sys

from softgen.cli import main

if __name__ == "__main__":
    sys.exit(main())
