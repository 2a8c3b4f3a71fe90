"""``python -m dpe5g``: the command line (``cli``)."""

from .cli.main import entry

entry()
