"""The results store's catalogue: every Monte Carlo experiment the book's chapters and figures run
(``store_experiments``), at the trial counts they read.

It stands above the studies that define the experiments and below the commands that fill or check the store
(``dpe5g warm``, ``reproduce``, ``verify``), which pass its list to ``verify``.
"""

from __future__ import annotations

from ..simulation import code_key
from ..simulation.experiment import Experiment
from . import city as city_study, city_density, city_second, city_sensitivity, nlos as nlos_study, paper, readings


def store_experiments() -> list[Experiment]:
    """Every Monte Carlo experiment the book's chapters and figures run, which the results store holds.

    They come at the trial counts the chapters read, in the order they first need them (the DPE chapter and the
    Fig. 9 to NLoS chapters); ``run`` reuses a longer run's first trials, so an experiment whose first trials a chapter
    reads at a smaller count appears once, at its largest.  ``dpe5g warm`` and ``dpe5g reproduce`` run them;
    ``tests/book/test_warm.py`` checks the list against the runs a book build recorded.

    Returns
    -------
    list of Experiment
        One per stored entry.
    """
    out = [*paper.ring_window_experiments().values(), *paper.ring_centring_experiments().values(),
           paper.fig9_honest(), paper.fig9_truth(), *paper.urban_window_experiments().values(),
           paper.fig9_low_snr(), paper.fig9_link_budget(), paper.fig9_power(paper.REUSE_COMPARE_TRIALS),
           paper.fig9_power(paper.REUSE_COMPARE_TRIALS, paper.REUSE, co_channel=False),
           paper.fig9_power(reuse=paper.REUSE), *paper.fig10().values(), paper.fig10_reuse()["two_of_four"]]
    for name in readings.READINGS:
        out += [v for k, v in readings.experiments(name).items() if k != "otdoa_detector"]
    out += [paper.fig9_all_los(*c) for c in paper.ALL_LOS_CASES]
    out.append(paper.ml_toa_experiment())
    for flat, fpa in paper.first_path_comparison().values():
        out += [flat, fpa]
    out += nlos_study.all_experiments()
    out += city_study.all_experiments()
    out += city_sensitivity.all_experiments()
    out += city_density.all_experiments()
    out += city_second.all_experiments()
    longest, version = {}, code_key.code_version()
    for e in out:  # one entry per cached run (the name and config without the trial count), at its largest count
        k = (e.run.name, e.key(version))
        longest[k] = e if k not in longest or e.run.n_trials > longest[k].run.n_trials else longest[k]
    seen, order = set(), []
    for e in out:
        k = (e.run.name, e.key(version))
        if k not in seen:
            seen.add(k)
            order.append(longest[k])
    return order
