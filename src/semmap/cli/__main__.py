"""``python -m semmap.cli``: the ``semmap`` command."""

from semmap.cli import main

main()
