"""``python -m servogym``: the ``servogym`` command."""

from servogym.cli import main

main()
