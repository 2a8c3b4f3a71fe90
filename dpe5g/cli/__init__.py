"""The ``dpe5g`` command line: its commands (``main``) and its parser (``parser``)."""
