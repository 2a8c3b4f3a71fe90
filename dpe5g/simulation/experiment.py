"""The Monte Carlo experiment (Section IV), in four parts a reader can hold — the scenario (``Scenario``), the links'
SNR (``Links``), the receiver (``Receiver``) and the run (``Run``), each a frozen config with its own validation —
and the key of its results (the config, the code it runs, the deployment file, the numerical libraries).

Pipeline: ``experiment`` (what to run) → ``draw`` (one trial's draws) → ``receiver`` (correlograms and fixes) →
``trials`` (the per-trial programs) → ``engine`` (batches, threads, compiled programs) → ``store`` (chunks on disk)
→ ``results`` (per-trial arrays and their statistics).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field

import numpy as np

from ..city.dataset import city_at
from ..common import _checks
from ..phy import channel, deployment, nr, propagation as scenario, signal
from ..phy.nr import C
from ..receivers import otdoa, search_config
from ..receivers.dpe_nlos import CLOCK_NLOS_QUANTILE, MIN_MEDIAN_S, MIN_SIGMA_LG
from .code_key import code_version

#: settings added after the results store was first filled, with their defaults: at its default such a setting is
#: left out of ``Experiment.config_key``, so the stored results of every experiment that does not use it keep their key
LATER_SETTINGS = {"nlos_excess_median_s": 0.0, "nlos_excess_sigma_lg": 0.0, "snr_offset_db": 0.0,
                  "clock_window": "clock", "channel": "tdl", "otdoa_nlos": False, "dpe_nlos": False,
                  "nlos_prior": "scenario", "clock_prior_s": 0.0}

LOS_MODES = ("pr_los", "two_of_four", "all_los", "all_nlos", "free_space", "nearest_two_los")
SNR_MODES = ("fixed", "link_budget", "nearest")
#: PRS frequency reuse factors: 0 — the paper's model (full-band PRS on all N bins, one symbol, every link received
#: alone); R in ``nr.PRS_COMB_SIZES`` — TS 38.211's comb R, fully staggered over R symbols, BSs on R resources
PRS_REUSES = (0,) + nr.PRS_COMB_SIZES
CENTRINGS = ("truth", "prior", "otdoa")
PRIOR_KINDS = ("gaussian", "disc")
#: the clock-bias window of a receiver not centred on the truth (``Experiment.receiver_search``): "clock" — the support
#: of the clock prior; "clock_nlos" — widened by the 99th percentile of the NLoS excess delay; "free" — no clock prior
CLOCK_WINDOWS = ("clock", "clock_nlos", "free")
#: the excess-delay law the NLoS-aware receivers assume (the "clock_nlos" window and ``dpe_nlos``): "scenario" — the
#: law that drew the scenario's delays; "umi" — TR 38.901's UMi row, for a channel with no law of its own (traced)
NLOS_PRIORS = ("scenario", "umi")
#: both OTDoA ToA detectors run on the same signals; the first is the main baseline, the second the naive one
OTDOA_DETECTORS = ("first_path", "peak")
#: the channel sources: "tdl" — TR 38.901's TDL models (``draw``); "traced" — the ray-traced paths of the city the
#: deployment names (``city_draw``)
CHANNELS = ("tdl", "traced")


@dataclass(frozen=True)
class Scenario:
    """Where the UE is and how its links propagate (Section III).

    Attributes
    ----------
    deployment : str
        A packaged deployment by name (``deployment.BUILTIN``: "tst", "ring", "ring-wide") or a path to a JSON/CSV
        deployment.
    los_mode : str
        "pr_los" — each link LoS with the probability of eq. (11); "two_of_four" — the paper's stated case for Fig. 10:
        of the four nearest links, two (chosen at random) LoS and two NLoS (needs max(m_values) = 4); "all_los" — every
        link LoS (TDL-D; not the paper's: the bounds chapter compares it with the Cramér–Rao bound); "all_nlos" — every
        link NLoS (TDL-C; the DPE chapter's ring studies); "free_space" — every link LoS with one path of unit power and
        uniform phase at the geometric delay, no multipath (the bounds chapter's check of the ML ToA against its bound);
        "nearest_two_los" — of the four nearest links, the two nearest LoS and the two farther NLoS (a deterministic
        reading of the paper's Fig. 10 case; needs max(m_values) = 4).
    delay_spread_s, k_factor_db : float
        TDL-C (NLoS) / TDL-D (LoS) at this delay spread (s); TDL-D's K (dB).
    delay_spread_def : str
        What delay_spread_s means for both profiles (``channel.DELAY_SPREAD_DEFS``): "rms", TR 38.901's RMS spread
        (default), or "span", first to last tap (the paper's text; the reproduction chapter's readings).
    clock_sigma_s, clock_bound_sigmas : float
        UE clock bias, Gaussian σ (s) truncated at ± bound · σ.
    prs_reuse : int
        ``PRS_REUSES``.  0 (default) — the paper's model: every link's PRS on all N bins in one symbol, received alone
        (its own noise, no other BS).  R > 0 — Table I's PRS frequency reuse: the PRS of TS 38.211 with comb R over R
        symbols on the 3276 active subcarriers (``nr.PrsPattern(R)``, the pilot energy of the paper's symbol), each BS
        on the comb offset and with the PRS ID of ``deployment.prs_plan`` (R resources).  Every BS of the deployment
        transmits; the UE receives on each resource the sum of its BSs' signals through their own channels, path loss
        and ToA, plus one noise (co-channel links share their REs and so their noise).  Needs per-BS power
        (``Links.snr_mode`` "link_budget" or "nearest") and the certified search, whose window taps are then spaced for
        the pilots' band (``receiver.receiver_window``).
    co_channel : bool
        With prs_reuse > 0, whether the co-channel BSs' signals are received (True, default) or left out (the pattern
        and the shared noise alone, for comparison).
    nlos_excess_median_s, nlos_excess_sigma_lg : float
        NLoS excess delay (``scenario.nlos_excess_delay``; ours, not the paper's): every path of an NLoS link arrives Δτ
        after the geometric delay, lg Δτ normal with median nlos_excess_median_s (s, in [0, 1e-6]) and standard
        deviation nlos_excess_sigma_lg (decades, in [0, 1]).  Off by default (median 0), when the first tap sits at the
        geometric delay as in TR 38.901's TDL models.
    channel : str
        ``CHANNELS``: "tdl" (default) or "traced", the paths ray-traced in the city that ``deployment`` names, by
        its name in the results store or by its deployment file in a folder of one's own (``city.dataset.city_at``;
        ``traced_draw``: LoS from the geometry, so los_mode stays "pr_los"; no PRS reuse, no added excess delay).
    """

    deployment: str = "tst"
    los_mode: str = "pr_los"
    delay_spread_s: float = 65e-9
    delay_spread_def: str = "rms"
    k_factor_db: float = 13.3
    clock_sigma_s: float = 5e-9
    clock_bound_sigmas: float = 3.0
    prs_reuse: int = 0
    co_channel: bool = True
    nlos_excess_median_s: float = 0.0
    nlos_excess_sigma_lg: float = 0.0
    channel: str = "tdl"

    def __post_init__(self):
        _checks.plain_fields(self)  # lists and NumPy values as the plain Python they hash as
        _checks.one_of("los_mode", self.los_mode, LOS_MODES)
        _checks.one_of("delay_spread_def", self.delay_spread_def, channel.DELAY_SPREAD_DEFS)
        channel.check_delay_spread(self.delay_spread_s)
        _checks.in_range("k_factor_db", self.k_factor_db, -30.0, 60.0, "dB")
        _checks.in_range("clock_sigma_s", self.clock_sigma_s, 0.0, 1e-6, "s")
        _checks.in_range("clock_bound_sigmas", self.clock_bound_sigmas, 0.1, 10.0, "σ")
        _checks.one_of("prs_reuse", self.prs_reuse, PRS_REUSES)
        if not isinstance(self.co_channel, bool):
            raise ValueError(f"co_channel must be True or False, got {self.co_channel!r}")
        _checks.in_range("nlos_excess_median_s", self.nlos_excess_median_s, 0.0, 1e-6, "s (30 ns is 3e-8)")
        _checks.in_range("nlos_excess_sigma_lg", self.nlos_excess_sigma_lg, 0.0, 1.0, "decades")
        if self.nlos_excess_median_s and self.prs_reuse:
            raise ValueError("nlos_excess_median_s > 0 is not modelled with prs_reuse > 0 (the co-channel BSs' "
                             "channels have no excess delay): use one or the other")
        _checks.one_of("channel", self.channel, CHANNELS)
        if self.channel == "traced" and (self.los_mode != "pr_los" or self.prs_reuse or self.nlos_excess_median_s):
            raise ValueError("channel 'traced' takes LoS and every delay from the traced paths: leave los_mode "
                             "'pr_los', prs_reuse 0 and nlos_excess_median_s 0")
        if self.channel == "traced":  # a traced city: by name in the store, or its deployment file in a folder
            city_at(self.deployment)


@dataclass(frozen=True)
class Links:
    """The links' SNR.

    Attributes
    ----------
    snr_mode : str
        "fixed" — every link at each SNR of ``snrs_db``, as Fig. 9; "link_budget" — each link's SNR from the UMi path
        loss and shadow fading (``budget``), ``snrs_db`` must be (); "nearest" — the nearest BS's link at each SNR of
        ``snrs_db``, every other BS (interferers included) at its received-power difference from it (transmit power,
        path loss and shadow fading of ``budget``'s model): Fig. 9's SNR axis with per-link power from the path loss.
    snrs_db : tuple of float
        The SNRs, dB (per-sample SNR of ``dpe5g.phy.signal`` unless snr_convention says otherwise).
    snr_convention : str
        What the SNRs mean (``signal.SNR_CONVENTIONS``), in both SNR modes: "per_sample" (default) or "total", after
        correlation over the N samples (the per-sample SNR is then 10 log10 N dB lower).  The results' link_snr_db is
        always the per-sample SNR the links were simulated at.
    budget : scenario.LinkBudget
        The link budget.
    snr_offset_db : float
        With snr_mode "link_budget", dB added to every link's SNR (our sweep of Fig. 10's unstated SNR, in [-60, 20]); 0
        otherwise.
    """

    snr_mode: str = "fixed"
    snrs_db: tuple[float, ...] = (10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0)
    snr_convention: str = "per_sample"
    budget: scenario.LinkBudget = field(default_factory=scenario.LinkBudget)
    snr_offset_db: float = 0.0

    def __post_init__(self):
        _checks.plain_fields(self)  # lists and NumPy values as the plain Python they hash as
        _checks.one_of("snr_mode", self.snr_mode, SNR_MODES)
        _checks.one_of("snr_convention", self.snr_convention, signal.SNR_CONVENTIONS)
        if self.snr_mode != "link_budget":
            if len(self.snrs_db) == 0:
                raise ValueError(f"snrs_db must list at least one SNR (dB) when snr_mode is {self.snr_mode!r}")
            signal.check_snr_db(np.asarray(self.snrs_db))
            if len(set(self.snrs_db)) != len(self.snrs_db):
                raise ValueError(f"snrs_db must not repeat an SNR (each would give the same rows twice), got "
                                 f"{self.snrs_db!r}")
        elif len(self.snrs_db):
            raise ValueError(f"snrs_db must be empty when snr_mode is 'link_budget' (the SNR comes from the path "
                             f"loss), got {self.snrs_db!r}")
        _checks.in_range("snr_offset_db", self.snr_offset_db, -60.0, 20.0, "dB")
        if self.snr_offset_db and self.snr_mode != "link_budget":
            raise ValueError(f"snr_offset_db applies to snr_mode 'link_budget' only (the other modes list their "
                             f"SNRs), got {self.snr_offset_db!r} with {self.snr_mode!r}")

    @property
    def n_snr(self) -> int:
        """SNR indices per trial, one per SNR of ``snrs_db`` (one for the link budget)."""
        return max(len(self.snrs_db), 1)


@dataclass(frozen=True)
class Receiver:
    """What the receiver uses and where it looks.

    Attributes
    ----------
    m_values : tuple of int
        Numbers of nearest BSs used by the DPE (each ≤ the deployment's BS count).
    centring : str
        Where the receiver centres its search window.  "truth" — on the true position and clock bias (the paper's
        set-up, a labelled comparison only: the window's position and grid phase then carry the truth); "prior" — on
        truth + an error drawn from the stated prior (``prior_kind``, ``prior_scale_m``), keyed per trial; "otdoa" — on
        that trial's OTDoA fix (detector ``toa_method``; needs ``otdoa``).  In "prior" and "otdoa" the clock-bias window
        is centred on 0 and spans the clock model's support, ± clock_bound_sigmas · clock_sigma_s · c
        (``Experiment.receiver_search``), so nothing about the truth reaches the search.
    prior_kind, prior_scale_m : str, float
        "gaussian" — an isotropic horizontal error with σ = prior_scale_m (m) per axis; "disc" — uniform over a disc of
        radius prior_scale_m.
    search : search_config.SearchConfig
        The DPE search.
    otdoa : bool
        Also run the OTDoA baseline (``dpe5g.receivers.otdoa``) on the same received signals, for every SNR and M, with both ToA
        detectors of ``OTDOA_DETECTORS``.
    toa_method : str
        The detector whose OTDoA fix centres the search in centring "otdoa".
    otdoa_nlos : bool
        Also run the NLoS-aware OTDoA receiver (``dpe5g.receivers.otdoa_nlos``) on the first-path ToAs, for every SNR and M:
        each link's ToA standard deviation from its correlogram (eq. (O1)), the weighted fix, the residual test and
        its exclusions; needs ``otdoa``.
    clock_window : str
        ``CLOCK_WINDOWS``, the clock-bias window in centrings "prior" and "otdoa": "clock" (default) the clock prior's
        support; "clock_nlos" that support widened on both sides by the ``CLOCK_NLOS_QUANTILE`` point of c·Δτ of the
        excess-delay law the receiver assumes (``nlos_prior``; a law, not the drawn delays); "free" no clock prior:
        ± √2 half_width_m, centred in centring "otdoa" on the c δt its OTDoA fix implies (``toa_fit.implied_bias_m``).
    clock_prior_s : float
        The UE clock's σ the receiver assumes, seconds (1e-10 to 1e-6): its window spans ± clock_bound_sigmas ·
        clock_prior_s · c; 0 (default): the scenario's clock model, clock_sigma_s.
    dpe_nlos : bool
        The DPE is the NLoS-aware one (``dpe5g.receivers.dpe_nlos``, eq. (D1)): each link's excess delay integrated out under
        the excess-delay law it assumes (``nlos_prior``) and eq. (11)'s LoS probability; needs the certified search, a
        centring other than "truth" and clock_window "clock_nlos".
    nlos_prior : str
        ``NLOS_PRIORS``, the excess-delay law of clock_window "clock_nlos" and of dpe_nlos (``Experiment.excess_law``).
    """

    m_values: tuple[int, ...] = (6, 12, 18, 24)
    centring: str = "truth"
    prior_kind: str = "gaussian"
    prior_scale_m: float = 5.0
    search: search_config.SearchConfig = field(default_factory=search_config.SearchConfig)
    otdoa: bool = False
    toa_method: str = "first_path"
    clock_window: str = "clock"
    otdoa_nlos: bool = False
    dpe_nlos: bool = False
    nlos_prior: str = "scenario"
    clock_prior_s: float = 0.0

    def __post_init__(self):
        _checks.plain_fields(self)  # lists and NumPy values as the plain Python they hash as
        if len(self.m_values) == 0 or list(self.m_values) != sorted(set(self.m_values)):
            raise ValueError(f"m_values must be a non-empty increasing tuple of BS counts, got {self.m_values!r}")
        for m in self.m_values:
            _checks.integer("m_values entry", m, 3, 1024)
        _checks.one_of("centring", self.centring, CENTRINGS)
        _checks.one_of("prior_kind", self.prior_kind, PRIOR_KINDS)
        _checks.in_range("prior_scale_m", self.prior_scale_m, 0.0, 1000.0, "m")
        _checks.one_of("toa_method", self.toa_method, otdoa.TOA_METHODS)
        if self.centring == "otdoa" and not self.otdoa:
            raise ValueError("centring 'otdoa' centres the search on the OTDoA fix; set otdoa=True")
        if self.otdoa_nlos and not self.otdoa:
            raise ValueError("otdoa_nlos runs the NLoS-aware OTDoA receiver on the OTDoA ToAs; set otdoa=True")
        _checks.one_of("clock_window", self.clock_window, CLOCK_WINDOWS)
        _checks.one_of("nlos_prior", self.nlos_prior, NLOS_PRIORS)
        if self.clock_prior_s != 0.0:
            _checks.in_range("clock_prior_s", self.clock_prior_s, 1e-10, 1e-6, "s")
        if (self.clock_window != "clock" or self.clock_prior_s) and self.centring == "truth":
            raise ValueError(f"clock_window {self.clock_window!r} and clock_prior_s set the window of a receiver not "
                             f"centred on the truth; centring 'truth' searches its own search.bias_half_width_m")
        if self.clock_window == "free" and (self.clock_prior_s or self.dpe_nlos):
            raise ValueError("clock_window 'free' is a window without a clock prior: it needs clock_prior_s 0 and "
                             "dpe_nlos False")


@dataclass(frozen=True)
class Run:
    """How many trials, from which seed.

    Attributes
    ----------
    name : str
        Label (cache directory prefix).
    n_trials, seed : int
        Trials t = 0 … n_trials-1 draw from fold_in(seed, t).
    chunk_trials : int
        Trials per cache file (results do not depend on it; resuming needs the same value).
    """

    name: str = "urban"
    n_trials: int = 5000
    seed: int = 9
    chunk_trials: int = 100

    def __post_init__(self):
        _checks.plain_fields(self)  # lists and NumPy values as the plain Python they hash as
        _checks.name("name", self.name)
        _checks.integer("n_trials", self.n_trials, 1, 10_000_000)
        _checks.integer("seed", self.seed, 0, 2**31 - 1)
        _checks.integer("chunk_trials", self.chunk_trials, 1, 100_000)


#: the part each setting of ``Experiment.build`` and ``Experiment.replace`` belongs to
PARTS = {"scenario": Scenario, "links": Links, "receiver": Receiver, "run": Run}
SETTINGS = {f.name: part for part, cls in PARTS.items() for f in dataclasses.fields(cls)}


@dataclass(frozen=True)
class Experiment:
    """One urban Monte Carlo experiment: its scenario, links, receiver and run, and the checks that tie them.

    Built from settings by ``Experiment.build(centring="prior", n_trials=400, ...)`` (each setting goes to its part,
    ``SETTINGS``), or from the parts themselves; ``replace`` changes settings the same way.

    Attributes
    ----------
    scenario, links, receiver, run : Scenario, Links, Receiver, Run
        The four parts.
    """

    scenario: Scenario = field(default_factory=Scenario)
    links: Links = field(default_factory=Links)
    receiver: Receiver = field(default_factory=Receiver)
    run: Run = field(default_factory=Run)

    def __post_init__(self):
        for part, cls in PARTS.items():
            if not isinstance(getattr(self, part), cls):
                raise ValueError(f"{part} must be a {cls.__name__}, got {getattr(self, part)!r}")
        sc, rx = self.scenario, self.receiver
        if sc.prs_reuse and rx.search.method != "bnb":
            raise ValueError("prs_reuse > 0 needs the certified search (search.method 'bnb', the receiver of centring "
                             "'prior' and 'otdoa'): its receiver window is spaced for the PRS band "
                             "(correlogram.band_tap_spacing), which the grid search's sample-shift window cannot be; "
                             f"got {rx.search.method!r}")
        if sc.prs_reuse and self.links.snr_mode == "fixed":
            raise ValueError("prs_reuse > 0 needs each BS's received power for its interference: snr_mode must be "
                             "'link_budget' or 'nearest', got 'fixed'")
        if rx.clock_window == "clock_nlos" and not self.excess_law()[0]:
            raise ValueError("clock_window 'clock_nlos' widens the clock window by an NLoS excess delay the receiver "
                             "assumes: set nlos_excess_median_s > 0 or nlos_prior 'umi'")
        if rx.nlos_prior != "scenario" and rx.clock_window != "clock_nlos":
            raise ValueError(f"nlos_prior {rx.nlos_prior!r} is read by clock_window 'clock_nlos' only")
        if rx.dpe_nlos and (rx.search.method != "bnb" or rx.clock_window != "clock_nlos"):
            raise ValueError("dpe_nlos integrates the NLoS excess delay out in the certified search: it needs "
                             f"search.method 'bnb' and clock_window 'clock_nlos', got {rx.search.method!r}, "
                             f"{rx.clock_window!r}")
        if rx.dpe_nlos and not (self.excess_law()[0] >= MIN_MEDIAN_S and self.excess_law()[1] >= MIN_SIGMA_LG):
            raise ValueError(f"dpe_nlos integrates over the log-normal excess delay it assumes: nlos_excess_median_s "
                             f"must be at least {MIN_MEDIAN_S:g} s and nlos_excess_sigma_lg at least {MIN_SIGMA_LG:g} "
                             f"decades (or nlos_prior 'umi'), got {self.excess_law()}")
        if sc.los_mode in ("two_of_four", "nearest_two_los") and max(rx.m_values) != 4:
            raise ValueError(f"los_mode {sc.los_mode!r} fixes the LoS state of the four nearest links; m_values must "
                             f"end in 4, got {rx.m_values!r}")

    @classmethod
    def build(cls, **settings) -> "Experiment":
        """An experiment from settings, each the field of one part (``SETTINGS``); the others at their defaults.

        Parameters
        ----------
        **settings
            Setting name to value.

        Returns
        -------
        Experiment
        """
        return cls()._with(settings)

    def replace(self, **settings) -> "Experiment":
        """A copy with ``settings`` changed, each in its part (``SETTINGS``).

        Parameters
        ----------
        **settings
            Setting name to value.

        Returns
        -------
        Experiment
        """
        return self._with(settings)

    def _with(self, settings: dict) -> "Experiment":
        unknown = sorted(set(settings) - set(SETTINGS))
        if unknown:
            raise ValueError(f"unknown experiment setting(s) {', '.join(unknown)}; the settings are "
                             f"{', '.join(SETTINGS)}")
        if settings.get("snr_mode") == "link_budget" and "snrs_db" not in settings:
            settings = {**settings, "snrs_db": ()}  # (its SNRs come from the path loss: no list to give)
        parts = {}
        for part in PARTS:
            mine = {k: v for k, v in settings.items() if SETTINGS[k] == part}
            parts[part] = dataclasses.replace(getattr(self, part), **mine) if mine else getattr(self, part)
        return Experiment(**parts)

    def receiver_search(self) -> search_config.SearchConfig:
        """The search the receiver runs: ``search`` as given for centring "truth"; otherwise its clock-bias window set.

        That window is ± clock_bound_sigmas · σ · c, σ the clock prior (``Receiver.clock_prior_s``, else the clock
        model's clock_sigma_s), centred on 0; with clock_window "clock_nlos" ± that plus the ``CLOCK_NLOS_QUANTILE``
        point of c·Δτ (``scenario.excess_quantile_s``); with "free" ± √2 half_width_m, centred where the OTDoA fix
        puts it (``trials.otdoa_centers``).  It is split into boxes of about ``box_m`` in c δt (at least
        ``bias_boxes``, at most 64).

        Returns
        -------
        search_config.SearchConfig
        """
        search = self.receiver.search
        if self.receiver.centring == "truth":
            return search
        sc, rx = self.scenario, self.receiver
        half_b = sc.clock_bound_sigmas * (rx.clock_prior_s or sc.clock_sigma_s) * C
        if rx.clock_window == "clock" and not rx.clock_prior_s:
            return dataclasses.replace(search, bias_half_width_m=half_b)
        if rx.clock_window == "clock_nlos":
            half_b += C * scenario.excess_quantile_s(*self.excess_law(), CLOCK_NLOS_QUANTILE)
        elif rx.clock_window == "free":
            half_b = math.sqrt(2.0) * search.half_width_m
        boxes = min(64, max(search.bias_boxes, math.ceil(2 * half_b / search.box_m)))
        return dataclasses.replace(search, bias_half_width_m=half_b, bias_boxes=boxes)

    def excess_law(self) -> tuple[float, float]:
        """The NLoS excess-delay law the receiver assumes (``Receiver.nlos_prior``): the scenario's, or TR 38.901's UMi
        row whatever the channel.

        Returns
        -------
        median_s, sigma_lg : float
            The log-normal's median (s; 0: no excess delay) and its σ of lg Δτ (decades).
        """
        if self.receiver.nlos_prior == "umi":
            row = scenario.TR38901_EXCESS_DELAY[scenario.NLOS_EXCESS_ROW]
            return row.median_s, row.sigma_lg
        return self.scenario.nlos_excess_median_s, self.scenario.nlos_excess_sigma_lg

    @property
    def n_snr(self) -> int:
        """SNR indices per trial (``Links.n_snr``)."""
        return self.links.n_snr

    def load_deployment(self) -> deployment.Deployment:
        """The scenario's deployment, checked against the receiver's M values.

        Returns
        -------
        deployment.Deployment

        Raises
        ------
        ValueError
            When an M of m_values exceeds the deployment's BS count.
        """
        dep = deployment.named(self.scenario.deployment)
        if max(self.receiver.m_values) > dep.n_bs:
            raise ValueError(f"m_values must not exceed the deployment's {dep.n_bs} base stations, "
                             f"got {self.receiver.m_values!r}")
        return dep

    def to_dict(self) -> dict:
        """The settings, flat: {setting: value} (``SETTINGS``).

        Returns
        -------
        dict
        """
        return {k: v for part in PARTS for k, v in dataclasses.asdict(getattr(self, part)).items()}

    def key(self, version: str | None = None) -> str:
        """Hash of the name, the config and the deployment file (``config_key``), and of the code and libraries.

        Leaves out ``n_trials`` and ``chunk_trials``: trial t's result depends on neither, so a longer run reuses a
        shorter one's chunks.

        Parameters
        ----------
        version : str or None
            ``code_version()`` where the caller took it already; None: computed here.

        Returns
        -------
        str
        """
        version = code_version() if version is None else version
        return hashlib.sha256(json.dumps([self.run.name, self.config_key(), version]).encode()).hexdigest()[:16]

    def config_key(self) -> str:
        """Hash of what trial t's result depends on besides the code.

        The settings without the name and the trial counts, and the deployment file's content.  The results store's key
        (``store.stored``): its entries record the code that computed them (``code_version``) and ``verify`` checks them
        against today's code.

        Returns
        -------
        str
        """
        d = self.to_dict()
        for k in ("name", "n_trials", "chunk_trials"):
            d.pop(k)
        for k, default in LATER_SETTINGS.items():  # at its default, a setting added later leaves the key as it was
            if d[k] == default:
                d.pop(k)
        h = hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode())
        h.update(deployment.digest(self.scenario.deployment).encode())
        return h.hexdigest()[:16]
