"""The Monte Carlo of Section IV: the experiment (``experiment``), one trial's draws behind one interface
(``trial_draw``) from the TDL channel (``draw``) or a traced city (``traced_draw``), the per-trial programs (``trials``),
the engine (``engine``) and its Dask cluster (``cluster``); the results (``results``), the code they come from
(``code_key``), the cache (``chunk_cache``), the committed store (``store``) and its check against today's code
(``verify``)."""
