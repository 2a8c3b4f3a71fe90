"""What every stage shares: input checks (``_checks``), files written atomically and read checked (``_io``), the
project's folders (``locations``) and the failures that are not bad input (``errors``)."""
