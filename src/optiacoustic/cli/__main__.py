"""``python -m optiacoustic.cli``: the same as the ``oas`` command."""

from . import main

main()
