"""The studies the book runs: the paper's experiments (``paper``), the readings of its claims (``readings``), the
receivers' choices (``choices``), the NLoS-bias chapter's (``nlos``), the ray-traced city's (``city``, ``city_channel``,
``city_errors``, ``city_sensitivity``), the statistics that compare them (``intervals``, ``significance``) and the
store's catalogue of them all (``catalog``)."""
