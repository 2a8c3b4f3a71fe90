"""The ray-traced city's experiments (ours, beyond the paper): Fig. 10's receivers on Sionna RT's paths.

Each is ``paper.fig10``'s experiment with LoS from eq. (11) and one change: the channel is the traced city's
(``Scenario.channel`` "traced", ``city_draw``), so each trial is one traced outdoor UE, its links the BSs it hears
strongest.  The honest receivers (the DPE centred on the OTDoA fix, which runs on the same signals) and, as a labelled
comparison, the paper's DPE centred on the truth.
"""

from __future__ import annotations

from . import paper
from .experiment import Experiment

#: the traced city (its deployment's and its dataset's name): Sionna RT's "munich" scene (``city_trace.CitySpec``)
CITY = "munich"
#: trials of every city experiment: the first CITY_TRIALS UEs that hear M BSs
CITY_TRIALS = 900
#: the numbers M of links: Fig. 10's 4
CITY_M = (4,)
#: the centrings run: the honest DPE (on the OTDoA fix, with both OTDoA detectors) and the paper's, on the truth
CITY_CENTRINGS = ("otdoa", "truth")


def city_fig10(m: int, centring: str, n_trials: int = CITY_TRIALS) -> Experiment:
    """Fig. 10's experiment (LoS from eq. (11), link-budget SNR) on the traced city, with M = m links.

    Parameters
    ----------
    m : int
        The links, the UE's m strongest.
    centring : str
        ``CITY_CENTRINGS``.
    n_trials : int
        Trials: the first n_trials UEs that hear m BSs.

    Returns
    -------
    Experiment
        "city-munich-m{m}-{centring}".
    """
    e = paper.fig10(n_trials)[("pr_los", centring)]
    return e.replace(name=f"city-{CITY}-m{m}-{centring}", deployment=CITY, channel="traced", m_values=(m,))


def all_experiments() -> list[Experiment]:
    """Every experiment of the city chapter, at the trial counts it reads.

    Returns
    -------
    list of Experiment
    """
    return [city_fig10(m, c) for m in CITY_M for c in CITY_CENTRINGS]
