"""``python -m dpe5g``: the command line (``cli``)."""

from .cli import entry

entry()
