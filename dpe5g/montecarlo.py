"""Monte Carlo engine of the urban study (Section IV): experiments as frozen configs, per-trial keys, cached chunks.

One trial = one UE position uniform over the deployment's region at the UE height, the ``max(m_values)`` nearest
BSs, a LoS/NLoS draw per link (eq. (11)), TDL-D (K = 13.3 dB) for LoS and TDL-C for NLoS links at 65 ns, a truncated
Gaussian clock bias and a unit noise spectrum, then for every SNR that noise scaled to the SNR's variance and a DPE
fix with each M in ``m_values`` (the M nearest of the same links, so the M curves share their channels and the SNRs
their noise draw: common random numbers).  The signal is simulated in the frequency domain, where both receivers
start (``signal.received_spectrum``; no inverse and forward FFT per link).  Every draw of trial t comes from
``fold_in(PRNGKey(seed), t)``.  Results therefore do not depend on the batch size, the chunk size or which chunks
come from the cache.

Results are cached per experiment in ``<cache>/<name>-<hash>/``, one ``.npz`` per chunk of trials, written atomically
(temporary file + rename), so an interrupted run resumes where it stopped and ends with results identical to an
uninterrupted one.  The hash covers the config, the code of every module the numbers depend on (docstrings and
comments left out), the deployment file, the numerical libraries' versions and the float precision.
"""

from __future__ import annotations

import ast
import dataclasses
import hashlib
import io
import json
import os
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import lru_cache, partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from . import _checks, channel, correlogram, deployment, dpe, nr, otdoa, scenario, signal
from ._io import atomic_write, remove_stale_temporaries
from .nr import C, PAPER

#: default cache directory: ``.cache/montecarlo`` next to the package (the repository root for an editable install);
#: the environment variable DPE5G_CACHE overrides it.
DEFAULT_CACHE = Path(__file__).resolve().parent.parent / ".cache" / "montecarlo"
_SOURCES = ("channel.py", "correlogram.py", "deployment.py", "dpe.py", "montecarlo.py", "nr.py", "otdoa.py", "scenario.py",
            "signal.py")

LOS_MODES = ("pr_los", "two_of_four", "all_los")
#: OTDoA ToA detector settings used by the engine (``dpe5g.otdoa.toa``'s defaults)
OTDOA_UPSAMPLE = 8
OTDOA_THRESHOLD_DB = -10.0
OTDOA_MAX_LEAD = 64
SNR_MODES = ("fixed", "link_budget", "nearest")
#: PRS frequency reuse factors: 0 — the paper's model (full-band PRS on all N bins, one symbol, every link received
#: alone); R in ``nr.PRS_COMB_SIZES`` — TS 38.211's comb R, fully staggered over R symbols, BSs on R resources
PRS_REUSES = (0,) + nr.PRS_COMB_SIZES
CENTRINGS = ("truth", "prior", "otdoa")
PRIOR_KINDS = ("gaussian", "disc")
#: both OTDoA ToA detectors run on the same signals; the first is the main baseline, the second the naive one
OTDOA_DETECTORS = ("first_path", "peak")


@dataclass(frozen=True)
class Experiment:
    """One urban Monte Carlo experiment.

    name : label (cache directory prefix).  n_trials, seed : trials t = 0 … n_trials-1 draw from fold_in(seed, t).
    snr_mode : "fixed" — every link at each SNR of ``snrs_db`` (per-sample SNR of ``dpe5g.signal``, dB), as Fig. 9;
        "link_budget" — each link's SNR from the UMi path loss and shadow fading (``link``), ``snrs_db`` must be ();
        "nearest" — the nearest BS's link at each SNR of ``snrs_db``, every other BS (interferers included) at its
        received-power difference from it (transmit power, path loss and shadow fading of ``link``'s model): Fig. 9's
        SNR axis with per-link power from the path loss.
    m_values : numbers of nearest BSs used by the DPE (each ≤ the deployment's BS count).
    los_mode : "pr_los" — each link LoS with the probability of eq. (11); "two_of_four" — the paper's stated case for
        Fig. 10: of the four nearest links, two (chosen at random) LoS and two NLoS (needs max(m_values) = 4);
        "all_los" — every link LoS (TDL-D; not the paper's: Chapter 8 compares it with the Cramér–Rao bound).
    centring : where the receiver centres its search window.  "truth" — on the true position and clock bias (the
        paper's set-up, a labelled comparison only: the window's position and grid phase then carry the truth);
        "prior" — on truth + an error drawn from the stated prior (``prior_kind``, ``prior_scale_m``), keyed per trial;
        "otdoa" — on that trial's OTDoA fix (detector ``toa_method``; needs ``otdoa``).  In "prior" and "otdoa" the
        clock-bias window is centred on 0 and spans the clock model's support, ± clock_bound_sigmas · clock_sigma_s
        · c (``receiver_search``), so nothing about the truth reaches the search.
    prior_kind, prior_scale_m : "gaussian" — an isotropic horizontal error with σ = prior_scale_m per axis;
        "disc" — uniform over a disc of radius prior_scale_m.
    delay_spread_s, k_factor_db : TDL-C (NLoS) / TDL-D (LoS) at this delay spread; TDL-D's K.
    delay_spread_def : what delay_spread_s means for both profiles (``channel.DELAY_SPREAD_DEFS``): "rms", TR
        38.901's RMS spread (default), or "span", first to last tap (the paper's text; Chapter 7's readings).
    snr_convention : what the SNRs mean (``signal.SNR_CONVENTIONS``), in both SNR modes: "per_sample" (default) or
        "total", after correlation over the N samples (the per-sample SNR is then 10 log10 N dB lower).  The results'
        link_snr_db is always the per-sample SNR the links were simulated at.
    clock_sigma_s, clock_bound_sigmas : UE clock bias, Gaussian σ truncated at ± bound · σ.
    search : the DPE search; link : the link budget; deployment : "tst" or a path to a JSON/CSV deployment.
    otdoa : also run the OTDoA baseline (``dpe5g.otdoa``) on the same received signals, for every SNR and M, with
        both ToA detectors of ``OTDOA_DETECTORS``;
    toa_method : the detector whose OTDoA fix centres the search in centring "otdoa".
    prs_reuse : ``PRS_REUSES``.  0 (default) — the paper's model: every link's PRS on all N bins in one symbol,
        received alone (its own noise, no other BS).  R > 0 — Table I's PRS frequency reuse: the PRS of TS 38.211
        with comb R over R symbols on the 3276 active subcarriers (``nr.PrsPattern(R)``, the pilot energy of the
        paper's symbol), each BS on the comb offset and with the PRS ID of ``deployment.prs_plan`` (R resources).
        Every BS of the deployment transmits; the UE receives on each resource the sum of its BSs' signals through
        their own channels, path loss and ToA, plus one noise (co-channel links share their REs and so their noise).
        Needs per-BS power: snr_mode "link_budget" or "nearest"; and the certified search, whose window taps are
        then spaced for the pilots' band (``_receiver_window``).
    co_channel : with prs_reuse > 0, whether the co-channel BSs' signals are received (True, default) or left out
        (the pattern and the shared noise alone, for comparison).
    chunk_trials : trials per cache file (results do not depend on it; resuming needs the same value).
    """

    name: str = "urban"
    n_trials: int = 5000
    seed: int = 9
    snr_mode: str = "fixed"
    snrs_db: tuple[float, ...] = (10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0)
    m_values: tuple[int, ...] = (6, 12, 18, 24)
    los_mode: str = "pr_los"
    centring: str = "truth"
    prior_kind: str = "gaussian"
    prior_scale_m: float = 5.0
    delay_spread_s: float = 65e-9
    delay_spread_def: str = "rms"
    snr_convention: str = "per_sample"
    k_factor_db: float = 13.3
    clock_sigma_s: float = 5e-9
    clock_bound_sigmas: float = 3.0
    search: dpe.SearchConfig = field(default_factory=dpe.SearchConfig)
    link: scenario.LinkBudget = field(default_factory=scenario.LinkBudget)
    deployment: str = "tst"
    otdoa: bool = False
    toa_method: str = "first_path"
    prs_reuse: int = 0
    co_channel: bool = True
    chunk_trials: int = 100

    def __post_init__(self):
        _checks.integer("n_trials", self.n_trials, 1, 10_000_000)
        _checks.integer("seed", self.seed, 0, 2**31 - 1)
        _checks.integer("chunk_trials", self.chunk_trials, 1, 100_000)
        _checks.one_of("snr_mode", self.snr_mode, SNR_MODES)
        _checks.one_of("los_mode", self.los_mode, LOS_MODES)
        _checks.one_of("centring", self.centring, CENTRINGS)
        _checks.one_of("toa_method", self.toa_method, otdoa.TOA_METHODS)
        _checks.one_of("prior_kind", self.prior_kind, PRIOR_KINDS)
        _checks.one_of("delay_spread_def", self.delay_spread_def, channel.DELAY_SPREAD_DEFS)
        _checks.one_of("snr_convention", self.snr_convention, signal.SNR_CONVENTIONS)
        _checks.in_range("prior_scale_m", self.prior_scale_m, 0.0, 1000.0, "m")
        if self.centring == "otdoa" and not self.otdoa:
            raise ValueError("centring 'otdoa' centres the search on the OTDoA fix; set otdoa=True")
        _checks.one_of("prs_reuse", self.prs_reuse, PRS_REUSES)
        if not isinstance(self.co_channel, bool):
            raise ValueError(f"co_channel must be True or False, got {self.co_channel!r}")
        if self.prs_reuse and self.search.method != "bnb":
            raise ValueError("prs_reuse > 0 needs the certified search (search.method 'bnb'): its receiver window is "
                             "spaced for the PRS band (correlogram.band_tap_spacing), which the grid search's "
                             f"sample-shift window cannot be; got {self.search.method!r}")
        if self.prs_reuse and self.snr_mode == "fixed":
            raise ValueError("prs_reuse > 0 needs each BS's received power for its interference: snr_mode must be "
                             "'link_budget' or 'nearest', got 'fixed'")
        if self.snr_mode != "link_budget":
            if len(self.snrs_db) == 0:
                raise ValueError(f"snrs_db must list at least one SNR (dB) when snr_mode is {self.snr_mode!r}")
            signal.check_snr_db(np.asarray(self.snrs_db))
        elif len(self.snrs_db):
            raise ValueError(f"snrs_db must be empty when snr_mode is 'link_budget' (the SNR comes from the path "
                             f"loss), got {self.snrs_db!r}")
        if len(self.m_values) == 0 or list(self.m_values) != sorted(set(self.m_values)):
            raise ValueError(f"m_values must be a non-empty increasing tuple of BS counts, got {self.m_values!r}")
        for m in self.m_values:
            _checks.integer("m_values entry", m, 3, 1024)
        if self.los_mode == "two_of_four" and max(self.m_values) != 4:
            raise ValueError(f"los_mode 'two_of_four' fixes the LoS state of the four nearest links; m_values must "
                             f"end in 4, got {self.m_values!r}")
        channel.check_delay_spread(self.delay_spread_s)
        _checks.in_range("k_factor_db", self.k_factor_db, -30.0, 60.0, "dB")
        _checks.in_range("clock_sigma_s", self.clock_sigma_s, 0.0, 1e-6, "s")
        _checks.in_range("clock_bound_sigmas", self.clock_bound_sigmas, 0.1, 10.0, "σ")

    def receiver_search(self) -> dpe.SearchConfig:
        """The search the receiver runs: ``search`` as given for centring "truth"; otherwise with the clock-bias
        window set from the clock model (± clock_bound_sigmas · clock_sigma_s · c, centred on 0)."""
        if self.centring == "truth":
            return self.search
        return dataclasses.replace(self.search, bias_half_width_m=self.clock_bound_sigmas * self.clock_sigma_s * C)

    @property
    def n_snr(self) -> int:
        return max(len(self.snrs_db), 1)

    def load_deployment(self) -> deployment.Deployment:
        dep = deployment.tst() if self.deployment == "tst" else deployment.load_deployment(self.deployment)
        if max(self.m_values) > dep.n_bs:
            raise ValueError(f"m_values must not exceed the deployment's {dep.n_bs} base stations, "
                             f"got {self.m_values!r}")
        return dep

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def key(self) -> str:
        """Hash of the config, of the code (``code_digest``) and data the results depend on, and of the numerical
        libraries' versions and JAX's precision.  Leaves out ``n_trials`` and ``chunk_trials``: trial t's result
        depends on neither, so a longer run reuses a shorter one's chunks."""
        h = hashlib.sha256()
        d = self.to_dict()
        d.pop("chunk_trials")
        d.pop("n_trials")
        h.update(json.dumps(d, sort_keys=True, default=str).encode())
        here = Path(__file__).resolve().parent
        for name in _SOURCES:
            h.update(code_digest(here / name))
        h.update(_deployment_digest(self).encode())
        h.update(json.dumps(numerics()).encode())
        return h.hexdigest()[:16]


def code_digest(path: Path) -> bytes:
    """A module's code for the cache key: its syntax tree without docstrings, comments or line numbers, so that
    editing the prose of a module does not invalidate cached results, while any change of code does.  Remembered per
    file version (path, modification time and size: an edited file is parsed again), as parsing costs about 40 ms
    and every key reads every module."""
    st = Path(path).stat()
    return _code_digest(str(Path(path).resolve()), st.st_mtime_ns, st.st_size)


@lru_cache(maxsize=64)
def _code_digest(path: str, mtime_ns: int, size: int) -> bytes:
    tree = ast.parse(Path(path).read_text())
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and body
                and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree).encode()


def numerics() -> dict:
    """What else the numbers depend on: the versions of the numerical libraries (the OTDoA baseline's convex solver
    included) and JAX's float precision."""
    from importlib.metadata import version

    return {**{lib: version(lib) for lib in ("jax", "jaxlib", "numpy", "cvxpy", "clarabel")},
            "x64": bool(jax.config.jax_enable_x64)}


@dataclass(frozen=True)
class Results:
    """Per-trial results of an experiment (arrays over trials t, SNR index s, M index j, link i of the nearest).

    ue_xyz (T, 3) m; clock_bias_s (T,); bs_index (T, I) deployment index of the i-th nearest BS; los (T, I) bool;
    link_snr_db (T, S, I) per-sample SNR of each link; link_sinr_db (T, S, I) its SINR (co-channel interference of
    ``prs_reuse`` and thermal noise; equal to the SNR without interference); est_xyz (T, S, J, 3) m;
    est_bias_s (T, S, J);
    error_m (T, S, J) horizontal error; center_xyz (T, S, J, 3) the search window's centre; edge (T, S, J) the fix
    lies on the window's boundary (flagged); gap (T, S, J) the certified relative gap (NaN for the grid search);
    certified (T, S, J).  With ``otdoa``, per detector d of ``OTDOA_DETECTORS``: otdoa_toa_s (T, S, D, I) the
    estimated ToAs (clock bias included), otdoa_xyz (T, S, D, J, 3), otdoa_error_m (T, S, D, J), otdoa_ok
    (T, S, D, J) False where the fix is flagged.
    """

    experiment: Experiment
    ue_xyz: np.ndarray
    clock_bias_s: np.ndarray
    bs_index: np.ndarray
    los: np.ndarray
    link_snr_db: np.ndarray
    link_sinr_db: np.ndarray
    est_xyz: np.ndarray
    est_bias_s: np.ndarray
    error_m: np.ndarray
    center_xyz: np.ndarray
    edge: np.ndarray
    gap: np.ndarray
    certified: np.ndarray
    otdoa_toa_s: np.ndarray | None = None
    otdoa_xyz: np.ndarray | None = None
    otdoa_error_m: np.ndarray | None = None
    otdoa_ok: np.ndarray | None = None

    FIELDS = ("ue_xyz", "clock_bias_s", "bs_index", "los", "link_snr_db", "link_sinr_db", "est_xyz", "est_bias_s",
              "error_m", "center_xyz", "edge", "gap", "certified")
    OTDOA_FIELDS = ("otdoa_toa_s", "otdoa_xyz", "otdoa_error_m", "otdoa_ok")

    def rmse_m(self) -> np.ndarray:
        """(S, J) RMSE of the horizontal error over trials."""
        return np.sqrt(np.mean(self.error_m**2, axis=0))

    def los_share(self, m: int | None = None) -> float:
        """Fraction of LoS links among the m nearest (all simulated links if None) over all trials."""
        return float(np.mean(self.los if m is None else self.los[:, :m]))

    def table(self) -> list[dict]:
        """Tidy rows: one per (trial, SNR, M) with the error, the estimate, the LoS count of the links used, their
        LoS flags nearest first ("L" LoS, "N" NLoS) and their per-sample SNR and SINR in dB, nearest first
        (";"-separated)."""
        e = self.experiment
        snrs = e.snrs_db if e.snr_mode != "link_budget" else ("link",)
        per_link = lambda a: ";".join(f"{v:.2f}" for v in a)
        rows = []
        for t in range(self.error_m.shape[0]):
            for s, snr in enumerate(snrs):
                for j, m in enumerate(e.m_values):
                    rows.append({"trial": t, "snr_db": snr, "m": m, "error_m": float(self.error_m[t, s, j]),
                                 "est_x_m": float(self.est_xyz[t, s, j, 0]), "est_y_m": float(self.est_xyz[t, s, j, 1]),
                                 "true_x_m": float(self.ue_xyz[t, 0]), "true_y_m": float(self.ue_xyz[t, 1]),
                                 "n_los": int(self.los[t, :m].sum()),
                                 "los_flags": "".join("L" if f else "N" for f in self.los[t, :m]),
                                 "link_snr_db": per_link(self.link_snr_db[t, s, :m]),
                                 "link_sinr_db": per_link(self.link_sinr_db[t, s, :m]),
                                 "edge": bool(self.edge[t, s, j]), "certified": bool(self.certified[t, s, j])})
                    if self.otdoa_error_m is not None:
                        for d, name in enumerate(OTDOA_DETECTORS):
                            rows[-1].update({f"otdoa_{name}_error_m": float(self.otdoa_error_m[t, s, d, j]),
                                             f"otdoa_{name}_ok": bool(self.otdoa_ok[t, s, d, j])})
        return rows

    def write_csv(self, path) -> None:
        """The tidy table as CSV."""
        import csv

        rows = self.table()
        with open(path, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)

    def write_json(self, path) -> None:
        """The tidy table as JSON, with the experiment's config beside it."""
        doc = {"experiment": json.loads(json.dumps(self.experiment.to_dict(), default=str)), "rows": self.table()}
        Path(path).write_text(json.dumps(doc, indent=1) + "\n")


def _profiles(e: Experiment):
    """The NLoS (TDL-C) and LoS (TDL-D) profiles of the experiment."""
    return (channel.tdl_profile("C", e.delay_spread_s, definition=e.delay_spread_def),
            channel.tdl_profile("D", e.delay_spread_s, e.k_factor_db, definition=e.delay_spread_def))


def trial_key(seed: int, t) -> jax.Array:
    """The key every draw of trial t comes from: fold_in(PRNGKey(seed), t)."""
    return jax.random.fold_in(jax.random.PRNGKey(seed), t)


def _trial_keys(seed: int, start: int, stop: int) -> jax.Array:
    return jax.vmap(lambda t: trial_key(seed, t))(jnp.arange(start, stop))


def _draw_fn(e: Experiment, dep: deployment.Deployment):
    """Build the traceable key → draws of the trial with that key (``trial_key``) and its noise-free received
    spectrum, shared by the engine and ``example``.  The seed is not read (it enters through the key), so one
    compiled engine serves every seed.

    Each link's channel is TDL-D if LoS and TDL-C if not: its gains and delays (padded with zero-gain taps to the
    longer profile) are returned, and its frequency response is ``channel.frequency_response`` of the profile it
    belongs to.  The received spectrum is ``signal.received_spectrum`` (the one signal path; ``received_noiseless``
    is its inverse DFT, which a test checks against the engine).

    Returns a dict: ue (3,), bias (), idx (I,), bs (I, 3), los (I,), prs (I, N), gains (I, L), delays (I, L) s,
    y0 (I, N) noise-free received spectrum (unit power), link_snr (S, I) per-sample SNR of each link, link_sinr
    (S, I) its SINR, noise (I, N) the trial's unit noise spectrum, per_link_power (bool, static: whether ``_noisy``
    gives each link its own received power, see there).  With ``prs_reuse``, also the resource of every link,
    res (I,), and their number n_res; with ``co_channel`` also the other BSs of the
    deployment, nearest first (X of them): res_x (X,), prs_x (X, N), y_x (X, N), snr_x (S, X).  Their draws come
    from fold_in(key, 2000), so the links' draws are those of the same experiment without reuse.
    """
    nlos, los_prof = _profiles(e)
    n_taps = max(nlos.n_taps, los_prof.n_taps)
    pad = lambda a, n=n_taps: np.pad(np.asarray(a), (0, n - len(a)))
    delays_c, delays_d = pad(nlos.delays_s), pad(los_prof.delays_s)
    if e.prs_reuse:  # TS 38.211's pattern; each BS on its resource (comb offset) with its PRS ID
        res_np, ids_np = dep.prs_plan(e.prs_reuse)
        pattern = nr.PrsPattern(e.prs_reuse)
        prs_all = jnp.asarray(np.stack([nr.prs_per_subcarrier(int(i), pattern, int(r))
                                        for i, r in zip(ids_np, res_np)]))
        res_all = jnp.asarray(res_np)
    else:
        prs_all = jnp.asarray(nr.prs_matrix(range(dep.n_bs)))  # PRS ID = deployment index
    bs_all = jnp.asarray(dep.bs_xyz)
    pw_all = jnp.asarray(dep.power_dbm)
    x0, y0, x1, y1 = dep.region
    m_max = max(e.m_values)
    n_x = dep.n_bs - m_max if e.prs_reuse else 0  # the other BSs, interferers
    snrs = jnp.asarray(e.snrs_db if e.snr_mode != "link_budget" else (0.0,), dtype=jnp.float64)

    def channels(los, k_c, k_d, n):
        """(n, N) frequency responses and (n, L) gains of n links with LoS flags ``los``."""
        g_c = jax.vmap(lambda kk: channel.draw_gains(nlos, kk))(jax.random.split(k_c, n))
        g_d = jax.vmap(lambda kk: channel.draw_gains(los_prof, kk))(jax.random.split(k_d, n))
        h = jnp.where(los[:, None], channel.frequency_response(g_d, los_prof.delays_s),
                      channel.frequency_response(g_c, nlos.delays_s))  # (n, N), eq. (5)
        gains = jnp.where(los[:, None], jnp.pad(g_d, ((0, 0), (0, n_taps - g_d.shape[1]))),
                          jnp.pad(g_c, ((0, 0), (0, n_taps - g_c.shape[1]))))
        return h, gains

    def received_dbm(d2d, bs, los, k_sf, n, sel):
        """Received power P_tx - PL - SF (dBm) of n links (deployment indices ``sel``), the in-band SNR's numerator."""
        pl = scenario.path_loss_umi_db(d2d, bs[:, 2], dep.ue_height_m, e.link.fc_hz, los)
        sf = jax.random.normal(k_sf, (n,)) * jnp.where(los, scenario.SIGMA_SF_LOS_DB, scenario.SIGMA_SF_NLOS_DB)
        return pw_all[sel] - pl - sf

    def draw(key):
        k_ue, k_los, k_c, k_d, k_b, k_sf, k_n = jax.random.split(key, 7)
        xy = jax.random.uniform(k_ue, (2,), minval=jnp.array([x0, y0]), maxval=jnp.array([x1, y1]))
        ue = jnp.concatenate([xy, jnp.array([dep.ue_height_m])])
        d2d = jnp.linalg.norm(bs_all[:, :2] - xy, axis=-1)
        order = jnp.argsort(d2d)
        idx = order[:m_max]  # nearest first
        bs = bs_all[idx]
        if e.los_mode == "pr_los":
            los = jax.random.uniform(k_los, (m_max,)) < scenario.los_probability(d2d[idx])
        elif e.los_mode == "all_los":
            los = jnp.ones(m_max, dtype=bool)
        else:  # two of the four nearest LoS, which two at random
            los = jax.random.permutation(k_los, jnp.array([True, True, False, False]))
        bias = scenario.clock_bias(k_b, e.clock_sigma_s, e.clock_bound_sigmas)
        h, gains = channels(los, k_c, k_d, m_max)
        prs = prs_all[idx]
        y_clean = signal.received_spectrum(prs, h, dpe.toa(ue, bs), bias)
        out = {}
        if e.snr_mode == "fixed":
            link_snr = signal.per_sample_snr_db(jnp.broadcast_to(snrs[:, None], (snrs.size, m_max)), e.snr_convention)
        else:
            rx = received_dbm(d2d[idx], bs, los, k_sf, m_max, idx)
            link_snr = _link_snr_db(e, rx, rx[0], snrs)
        if e.prs_reuse:
            out = {"res": res_all[idx], "n_res": e.prs_reuse}
        if e.prs_reuse and e.co_channel:  # every other BS transmits too: its draws, keyed apart from the links'
            idx_x = order[m_max:]
            out.update(res_x=res_all[idx_x], prs_x=prs_all[idx_x], y_x=jnp.zeros((0, prs.shape[1]), prs.dtype),
                       snr_x=jnp.zeros((link_snr.shape[0], 0)))
            if n_x:
                k_xl, k_xc, k_xd, k_xs = jax.random.split(jax.random.fold_in(key, 2000), 4)
                bs_x = bs_all[idx_x]
                los_x = (jnp.ones(n_x, dtype=bool) if e.los_mode == "all_los"
                         else jax.random.uniform(k_xl, (n_x,)) < scenario.los_probability(d2d[idx_x]))
                h_x, _ = channels(los_x, k_xc, k_xd, n_x)
                out["y_x"] = signal.received_spectrum(prs_all[idx_x], h_x, dpe.toa(ue, bs_x), bias)
                out["snr_x"] = _link_snr_db(e, received_dbm(d2d[idx_x], bs_x, los_x, k_xs, n_x, idx_x), rx[0], snrs)
        link_sinr = _sinr_db(e, link_snr, out)
        delays = jnp.where(los[:, None], delays_d, delays_c)
        noise = signal.awgn(k_n, y_clean.shape, 1.0)  # CN(0, 1) per bin, scaled per SNR by ``_noisy``
        return {"ue": ue, "bias": bias, "idx": idx, "bs": bs, "los": los, "prs": prs, "gains": gains,
                "delays": delays, "y0": y_clean, "link_snr": link_snr, "link_sinr": link_sinr, "noise": noise,
                "per_link_power": e.snr_mode != "fixed", **out}

    return draw


def _link_snr_db(e: Experiment, rx_dbm, rx_nearest_dbm, snrs) -> jax.Array:
    """Per-sample SNR (S, n) of links with received powers ``rx_dbm`` (n,) dBm: from the link budget (snr_mode
    "link_budget", S = 1), or the nearest link's SNR ``snrs`` (S,) plus the power difference (snr_mode "nearest");
    then read in the experiment's ``snr_convention``."""
    if e.snr_mode == "link_budget":
        snr = e.link.model_snr_db(rx_dbm - e.link.noise_dbm)[None, :]
    else:
        snr = snrs[:, None] + (rx_dbm - rx_nearest_dbm)[None, :]
    return signal.per_sample_snr_db(snr, e.snr_convention)


def _sinr_db(e: Experiment, link_snr, other: dict) -> jax.Array:
    """SINR (S, I) of every link: its SNR over 1 + the SNRs (linear) of the BSs on its resource (the other links
    and the other BSs of ``other``), all per sample, so the pilots' equal power cancels; the SNR itself without
    co-channel interference."""
    if "y_x" not in other:
        return link_snr
    p_link, p_x = 10.0 ** (link_snr / 10.0), 10.0 ** (other["snr_x"] / 10.0)
    res = jnp.concatenate([other["res"], other["res_x"]])
    per_res = jax.vmap(lambda p: jax.ops.segment_sum(p, res, num_segments=e.prs_reuse))(
        jnp.concatenate([p_link, p_x], axis=1))  # (S, R) total received power per resource, in noise units
    interference = per_res[:, other["res"]] - p_link
    return 10.0 * jnp.log10(p_link / (1.0 + interference))


def _noisy(d, s):
    """Received spectrum of SNR index s: the trial's noise-free spectrum plus σ_s times the trial's unit noise.

    The noise is drawn in the frequency domain, CN(0, 1) per bin, once per trial (``_draw_fn``), and scaled to
    each SNR's variance (``signal.noise_variance``): the DFT is unitary, so this is exactly time-domain AWGN of
    that variance.  One draw serves every SNR (common random numbers): each SNR's noise has the right distribution,
    and the SNRs of one trial differ only in the noise level, as its M values differ only in the links used.

    Scale.  With snr_mode "fixed" every link has unit signal power and noise σ_s² (one SNR for all links, so the
    common scale does not matter to the receivers).  Where the links' powers differ (snr_mode "link_budget" and
    "nearest") the spectra are what one receiver sees: one noise floor, CN(0, 1) per bin, and each BS's signal
    s_b/σ_b at its own received power (s_b of unit power, σ_b its noise level).  A receiver that scaled each link to
    unit signal power would need each link's true SNR, and the DPE cost of eq. (10), which sums the BSs' energies,
    would then weigh a weak link's noise as much as a strong link's signal.

    With PRS reuse (``res`` in the draws) the UE receives one signal per resource r, Y_r = Σ_{b on r} s_b/σ_b + η_r,
    and each link reads the Y_r of its resource: co-channel links read the same REs, so the same signal and the same
    noise (η_r is the unit noise of the nearest link on r).  Without ``co_channel`` the other BSs' signals are left
    out."""
    sigma = jnp.sqrt(signal.noise_variance(d["link_snr"][s], d["prs"]))
    if not d["per_link_power"]:  # snr_mode "fixed": every link at the same SNR, unit signal power
        return d["y0"] + sigma[:, None] * d["noise"]
    own = d["y0"] / sigma[:, None]  # in units of the noise: the link's own signal at its received power
    if "res" not in d:
        return own + d["noise"]
    res = d["res"]
    eta = d["noise"][jnp.argmax(res[None, :] == res[:, None], axis=1)]  # the nearest co-channel link's noise
    if "y_x" not in d:
        return own + eta
    sigma_x = jnp.sqrt(signal.noise_variance(d["snr_x"][s], d["prs_x"]))
    rx = jax.ops.segment_sum(jnp.concatenate([own, d["y_x"] / sigma_x[:, None]]),
                             jnp.concatenate([res, d["res_x"]]), num_segments=d["n_res"])
    return rx[res] + eta


def _noise_form(d):
    """The scales (a, b), each (S, I), with ``_noisy(d, s)`` = a[s, :, None] · y0 + b[s, :, None] · noise: every
    link reads its own noise-free spectrum and the trial's unit noise (no PRS reuse).  None with PRS reuse, where a
    link reads a sum over the BSs of its resource.  The receivers' correlograms are linear in the CIR estimate (grid)
    or in its energy's three parts (spline), so with this form they are computed from a basis per trial
    (``correlogram.energy_window_parts``, ``correlogram.spline_noise_basis``, mixed by ``correlogram.mix_parts``)
    instead of once per SNR."""
    if "res" in d:
        return None
    sigma = jnp.sqrt(signal.noise_variance(d["link_snr"], d["prs"]))  # (S, I), as ``_noisy``'s
    if not d["per_link_power"]:
        return jnp.ones_like(sigma), sigma
    return 1.0 / sigma, jnp.ones_like(sigma)


def _spline_correlograms(d, cfg: dpe.SearchConfig, window):
    """s → the certified search's spline coefficients (I, N·U) at SNR index s (``dpe.receiver_correlogram`` of
    ``_noisy(d, s)``'s LS spectrum with ``window``), traceable.  Without PRS reuse they are mixed from a basis of the
    trial computed once (``_noise_form``, ``correlogram.spline_noise_basis``: 4 inverse FFTs and 3 spline maps per BS
    per trial instead of 2 and 1 per SNR), equal to the per-SNR path up to round-off (~1e-16 relative; a test checks
    it)."""
    form = _noise_form(d)
    if form is None:
        return lambda s: dpe.receiver_correlogram(correlogram.ls_spectrum(_noisy(d, s), d["prs"]), cfg, window)
    a, b = form
    basis = correlogram.spline_noise_basis(correlogram.ls_spectrum(d["y0"], d["prs"]),
                                           correlogram.ls_spectrum(d["noise"], d["prs"]), window, cfg.spline_upsample)
    return lambda s: correlogram.mix_parts(basis, a[s], b[s])


def _grid_windows(d, cfg: dpe.SearchConfig):
    """The grid search's correlograms of the trial d, read only in windows (``dpe.grid_window``; W of N·U points):
    returns (parts, windows).  windows(s, start) → the pair (values (I, W), start) that ``dpe.search`` reads at SNR
    index s for windows starting at grid points start (I,), traceable.  The CIR estimates on T_s/U
    (``correlogram.cir_grid``, in ``correlogram.GRID_DTYPE``) are computed whole, the energies only in the window.

    Without PRS reuse (``_noise_form``) the received spectrum of SNR s is a_s y0 + b_s η, and the CIR estimates of
    y0 and η are computed once per trial (2 inverse FFTs of length U·N per BS instead of one per SNR); parts(start)
    → the three parts (3, I, W) of the windows (``correlogram.energy_window_parts``), which ``dpe.mixed_grid_fixes``
    reads for all SNRs at once, and windows mixes them (``correlogram.mix_parts``): equal to the per-SNR path up to
    complex64 round-off (~2e-7 relative; a test checks it).  With PRS reuse parts is None."""
    dt, u, taps, n = correlogram.GRID_DTYPE, cfg.upsample, cfg.n_taps, d["prs"].shape[-1]
    width = dpe.grid_window_cells(cfg, PAPER)
    form = _noise_form(d)

    def cir(y):
        return correlogram.cir_grid(correlogram.ls_spectrum(y, d["prs"]).astype(dt), u)

    if form is None:
        def windows(s, start):
            return correlogram.energy_window(correlogram.cir_window(cir(_noisy(d, s)), start, width, taps, u),
                                             taps, n), start
        return None, windows
    a, b = form
    # the two transforms in a loop: its input, the two spectra, is then computed once (XLA on the CPU would
    # otherwise fuse the noise draw and the signal's phasors into the zero padding of the transform, measured 2×)
    h0, hn = jax.lax.map(cir, jnp.stack([d["y0"], d["noise"]]))

    def parts(start):
        return correlogram.energy_window_parts(correlogram.cir_window(h0, start, width, taps, u),
                                               correlogram.cir_window(hn, start, width, taps, u), taps, n)

    def windows(s, start):
        return correlogram.mix_parts(parts(start), a[s], b[s]), start
    return parts, windows


def _prior_center(e: Experiment, ue, key) -> jax.Array:
    """Centring "prior": truth + a horizontal error from the stated prior, keyed by fold_in(trial key, 1000) so the
    trial's other draws are unchanged; the height is the known UE height and c δt is 0.  Returns (4,) metres."""
    key = jax.random.fold_in(key, 1000)
    if e.prior_kind == "gaussian":
        err = e.prior_scale_m * jax.random.normal(key, (2,))
    else:
        k_r, k_a = jax.random.split(key)
        r = e.prior_scale_m * jnp.sqrt(jax.random.uniform(k_r))
        a = 2 * jnp.pi * jax.random.uniform(k_a)
        err = r * jnp.stack([jnp.cos(a), jnp.sin(a)])
    return jnp.concatenate([ue[:2] + err, ue[2:3], jnp.zeros(1)])


def _prior_fn(e: Experiment, dep: deployment.Deployment):
    """Traceable key → the trial's "prior" window centre (4,) (only the UE draw is computed)."""
    draw = _draw_fn(e, dep)
    return lambda key: _prior_center(e, draw(key)["ue"], key)


def _toa_fn(e: Experiment, dep: deployment.Deployment):
    """Traceable t → (ToAs (S, D, I) of every link with each detector of ``OTDOA_DETECTORS`` (OTDoA step 1),
    the true UE position (3,) (to score the fixes), the indices (I,) of the nearest BSs)."""
    draw = _draw_fn(e, dep)

    def one(key):
        d = draw(key)

        def per_snr(s):
            g = correlogram.ls_spectrum(_noisy(d, s), d["prs"])
            return jnp.stack([otdoa.toa_from_spectrum(g, meth, OTDOA_UPSAMPLE, OTDOA_THRESHOLD_DB, OTDOA_MAX_LEAD,
                                                      PAPER.sample_period_s) for meth in OTDOA_DETECTORS])

        return jax.lax.map(per_snr, jnp.arange(d["link_snr"].shape[0])), d["ue"], d["idx"]

    return one


def _receiver_window(e: Experiment) -> np.ndarray:
    """The certified search's window (``correlogram.window_spectrum``) of ``e``'s receiver: L taps T_s apart for the
    paper's full-band pilots; with ``prs_reuse`` the pilots fill only the carrier's contiguous band of active
    subcarriers, and the taps are spaced ``correlogram.band_tap_spacing`` samples apart (their tap weights too), so that
    the window's energy stays the ML cost of L free taps (eq. (8) with the band's own orthogonal taps)."""
    cfg = e.receiver_search()
    if not e.prs_reuse:
        return correlogram.window_spectrum(cfg.n_taps, PAPER.n_fft, cfg.tap_weights(PAPER))
    s = correlogram.band_tap_spacing(PAPER)
    weights = correlogram.tap_weights(cfg.n_taps, cfg.window_decay_s, PAPER.sample_period_s * s)
    return correlogram.window_spectrum(cfg.n_taps, PAPER.n_fft, weights, tap_spacing=s)


def _window_free(e: Experiment) -> Experiment:
    """``e`` without what its per-trial function (``_trial_fn``, ``_bnb_prep_fn``) does not read: the name, the seed
    (it enters through the trial keys), the trial and chunk counts, how a non-truth window centre is obtained (it
    enters as an input), and, for the "bnb" search, the receiver window L and its weights (they enter as
    ``correlogram.window_spectrum``, an input).  Experiments that differ only in these share one compiled function
    (and, through JAX's persistent compilation cache, one compiled executable across processes)."""
    search = (dataclasses.replace(e.search, n_taps=1, window_decay_s=0.0) if e.search.method == "bnb"
              else e.search)
    d = Experiment()
    centre = {} if e.centring == "truth" else dict(centring="prior", prior_kind=d.prior_kind,
                                                    prior_scale_m=d.prior_scale_m, otdoa=False,
                                                    toa_method=d.toa_method)
    return dataclasses.replace(e, name="", seed=0, n_trials=1, chunk_trials=1, search=search, **centre)


@lru_cache(maxsize=8)
def _compiled_trial_fn(e: Experiment, deployment_digest: str):
    """One grid-search trial function per window-free experiment (``_window_free``) and deployment file content, so
    the jitted chunk runner compiles it once per process."""
    return _trial_fn(e, e.load_deployment())


@lru_cache(maxsize=8)
def _compiled_step_fn(build, e: Experiment, deployment_digest: str):
    """``build(e, deployment)``: the OTDoA step-1 function (``_toa_fn``) or the prior-centre function
    (``_prior_fn``) of ``e`` (name, seed and trial counts cleared by the caller), one object per experiment and
    deployment content, so the runs of one process that share it trace and compile it once."""
    return build(e, e.load_deployment())


def _deployment_digest(e: Experiment) -> str:
    dep = deployment.TST_FILE if e.deployment == "tst" else Path(e.deployment)
    return hashlib.sha256(dep.read_bytes()).hexdigest()


def _trial_fn(e: Experiment, dep: deployment.Deployment):
    """Build the traceable per-trial function of the grid search (trial key, ext_center (S, J, 4)) → result dict.
    ext_center (metres) is the window centre of every (SNR, M) in the non-truth centrings: the trial's prior centre,
    or its OTDoA fixes.  (The certified search runs as two programs instead, ``_bnb_prep_fn``.)"""
    draw = _draw_fn(e, dep)
    cfg = e.receiver_search()
    # one window centre for every M only when it is the truth: the window-free experiment this function is built
    # from (``_window_free``) names both external centrings "prior", and the OTDoA fixes differ between the M values
    shared_centre = e.centring == "truth"

    def one(key, ext_center):
        d = draw(key)
        c0 = jnp.concatenate([d["ue"], d["bias"][None] * C])  # read in centring "truth" only
        bs = d["bs"]
        parts, windows = _grid_windows(d, cfg)
        if shared_centre and parts is not None and not cfg.polish:  # every SNR's first level in one lookup
            start = dpe.grid_window(bs, c0, cfg, PAPER)
            a, b = _noise_form(d)
            r = dpe.mixed_grid_fixes(parts(start), start, a, b, bs, c0, cfg, e.m_values, PAPER)
            return _grid_result(d, r, jnp.broadcast_to(c0, r["q"].shape))

        def per_snr(s):
            g = correlogram.ls_spectrum(_noisy(d, s), d["prs"])  # read by the polish only
            if shared_centre:  # one window and one first level for every M
                corr = windows(s, dpe.grid_window(bs, c0, cfg, PAPER))
                r = dpe.nested_grid_fixes(corr, g, bs, c0, cfg, e.m_values, PAPER)
                return r, jnp.broadcast_to(c0, (len(e.m_values), 4))
            fixes, centers = [], []
            for j, m in enumerate(e.m_values):
                c = ext_center[s, j]
                corr = dpe.first_rows(windows(s, dpe.grid_window(bs, c, cfg, PAPER)), m)
                fixes.append(dpe.fix(g[:m], bs[:m], c, cfg, PAPER, corr=corr))
                centers.append(c)
            return ({k: jnp.stack([f[k] for f in fixes]) for k in ("q", "gap", "certified", "edge")},
                    jnp.stack(centers))

        r, centers = jax.lax.map(per_snr, jnp.arange(d["link_snr"].shape[0]))  # (S, J, ...)
        return _grid_result(d, r, centers)

    return one


def _grid_result(d, r, centers):
    """The grid trial's result dict from its draws d, its fixes r (``dpe.fix``'s dict, arrays (S, J, ...)) and
    window centres (S, J, 4) m."""
    q = r["q"]
    err = jnp.linalg.norm(q[..., :2] - d["ue"][:2], axis=-1)
    return {"ue_xyz": d["ue"], "clock_bias_s": d["bias"], "bs_index": d["idx"], "los": d["los"],
            "link_snr_db": d["link_snr"], "link_sinr_db": d["link_sinr"], "est_xyz": q[..., :3],
            "est_bias_s": q[..., 3] / C, "error_m": err, "center_xyz": centers[..., :3], "edge": r["edge"],
            "gap": r["gap"], "certified": r["certified"]}


def _bnb_prep_fn(e: Experiment, dep: deployment.Deployment):
    """The certified search's trials in two parts: this jitted (trial key, window, window centres ext (S, J, 4) m of
    the non-truth centrings) → (the trial's per-trial results, BS positions (I, 3) m, the window centres (S, J, 4) m,
    the part of each BS's spline correlogram each window reaches (``dpe.spline_window``: coefficients
    (S, J, I, cells + 3) and their first knots (S, J, I))), the draws and correlograms ``_trial_fn`` computes; then
    ``_bnb_fix_fn``.  Split so that the search, the slow part to compile, is compiled once per search config, M
    values and number of SNRs, for every experiment (the draws, LoS model, PRS reuse and receiver window enter
    through the coefficients) instead of once per experiment; the windows, not the whole correlograms, pass from one
    program to the other."""
    draw = _draw_fn(e, dep)
    cfg = e.receiver_search()

    def bnb_prep(key, window, ext):
        d = draw(key)
        c0 = jnp.concatenate([d["ue"], d["bias"][None] * C])  # read in centring "truth" only
        centers = jnp.broadcast_to(c0, ext.shape) if e.centring == "truth" else ext
        correlograms = _spline_correlograms(d, cfg, window)

        def per_snr(a):
            s, cen = a
            coef = correlograms(s)
            return jax.vmap(lambda c: dpe.spline_window(coef, d["bs"], c, cfg, PAPER))(cen)

        sls, starts = jax.lax.map(per_snr, (jnp.arange(d["link_snr"].shape[0]), centers))  # (S, J, I, ...)
        trial = {"ue_xyz": d["ue"], "clock_bias_s": d["bias"], "bs_index": d["idx"], "los": d["los"],
                 "link_snr_db": d["link_snr"], "link_sinr_db": d["link_sinr"]}
        return trial, d["bs"], centers, sls, starts

    return jax.jit(bnb_prep)


@lru_cache(maxsize=32)
def _bnb_fix_fn(cfg: dpe.SearchConfig, m_values: tuple[int, ...]):
    """The certified search's fixes of one trial, jitted: (BS positions (I, 3) m, window centres (S, J, 4) m, the
    windows of the spline correlograms (``dpe.spline_window``: (S, J, I, cells + 3) and (S, J, I))) → ``dpe.fix``'s
    dict, arrays (S, J, ...), with the M nearest BSs for each M of ``m_values``.  cfg is the receiver's search
    without its window L (``_fix_config``), so one program serves every experiment with that search, those M and as
    many SNRs."""
    def certified_fix(bs, centers, sls, starts):
        def per_snr(a):
            cen, sl, st = a
            fixes = [dpe.fix(None, bs[:m], cen[j], cfg, PAPER, corr=(sl[j, :m], st[j, :m]))
                     for j, m in enumerate(m_values)]
            return {k: jnp.stack([f[k] for f in fixes]) for k in ("q", "gap", "certified", "edge")}

        return jax.lax.map(per_snr, (centers, sls, starts))

    return jax.jit(certified_fix)


@jax.jit
def _score(q, ue):
    """Fixes q (..., 4) (x, y, z, c δt in metres) → their clock bias (...) s and horizontal error (...) m against
    the true UE position ue (3,): scored as ``_trial_fn`` scores its fixes, in XLA (NumPy rounds the same
    expressions differently in the last bit)."""
    return q[..., 3] / C, jnp.linalg.norm(q[..., :2] - ue[:2], axis=-1)


def _fix_config(e: Experiment) -> dpe.SearchConfig:
    """``e``'s receiver search as ``_bnb_fix_fn`` reads it: the window's L and weights enter through the
    coefficients, so they are cleared."""
    return dataclasses.replace(e.receiver_search(), n_taps=1, window_decay_s=0.0)


def example(e: Experiment, trial: int, snr_index: int = 0) -> dict:
    """The draws and received samples of one trial at one SNR index, exactly as the engine sees them (NumPy).

    Returns ue (3,), bias, idx (I,), bs (I, 3), los (I,), prs (I, N), gains (I, L), delays (I, L) s, y (I, N)
    received samples (the inverse DFT of the engine's received spectrum; in units of the noise where the links'
    powers differ, see ``_noisy``), y0 (I, N) the links' noise-free samples at unit power,
    link_snr (I,), link_sinr (I,); with ``prs_reuse`` also res, n_res and (with ``co_channel``) res_x, prs_x, y_x
    (the other BSs' noise-free spectra) and snr_x (X,) (``_draw_fn``).
    """
    dep = e.load_deployment()
    _checks.integer("trial", trial, 0, e.n_trials - 1)
    _checks.integer("snr_index", snr_index, 0, e.n_snr - 1)
    d = _draw_fn(e, dep)(trial_key(e.seed, trial))
    out = {k: np.asarray(v) for k, v in d.items() if k != "noise"}
    out["y"] = np.asarray(signal.ofdm_symbol(_noisy(d, snr_index)))
    out["y0"] = np.asarray(signal.ofdm_symbol(d["y0"]))
    out["link_snr"] = out["link_snr"][snr_index]
    out["link_sinr"] = out["link_sinr"][snr_index]
    if "snr_x" in out:
        out["snr_x"] = out["snr_x"][snr_index]
    return out


def draw_links(e: Experiment, n_trials: int) -> dict:
    """Link draws only (no DPE) for trials 0 … n_trials-1: LoS flags (T, I), per-sample link SNR and SINR
    (T, S, I), 2-D distances (T, I) in metres — the statistics Chapter 4 shows, from the same keys as the engine."""
    dep = e.load_deployment()
    draw = _draw_fn(e, dep)

    @jax.jit
    def one(key):
        d = draw(key)
        return d["los"], d["link_snr"], d["link_sinr"], jnp.linalg.norm(d["bs"][:, :2] - d["ue"][:2], axis=-1)

    los, snr, sinr, dist = jax.lax.map(one, _trial_keys(e.seed, 0, n_trials), batch_size=64)
    return {"los": np.asarray(los), "link_snr_db": np.asarray(snr), "link_sinr_db": np.asarray(sinr),
            "d2d_m": np.asarray(dist)}


@partial(jax.jit, static_argnames=("fn",))
def _run_batch(args, fn, shared=()):
    """fn(*a, *shared) for each a of ``args``, vmapped over their leading axis (the batch); ``shared`` goes to every
    call.  A batch of one trial calls fn on it directly (vmap would turn any while loop into a batched one that
    carries its state through a select at every step; the results are the same bits)."""
    if args[0].shape[0] == 1:
        return jax.tree.map(lambda o: o[None], fn(*(a[0] for a in args), *shared))
    return jax.vmap(lambda *a: fn(*a, *shared))(*args)


def _run_chunk(args, fn, batch_size: int, shared=(), workers: int = 1) -> dict | tuple:
    """fn(*a, *shared) for each a of ``args`` (NumPy arrays, trials on the leading axis), ``batch_size`` trials per
    call of one compiled batch function; the last batch is filled up by repeating its last trial, whose copies are
    dropped.  So the compiled program depends on the batch size, never on the chunk's length: a run of 3 trials
    reuses the executable of a run of 5000 (in this process, and through JAX's persistent cache in others).
    workers : batches computed at once, each in its own thread (XLA runs a call of the certified search's loops on
    one core, and releases the GIL while it runs); the first batch runs alone, so the program is traced and compiled
    once.  A batch's result depends only on its trials, never on the thread or the order.
    Returns fn's outputs as NumPy arrays, trials on the leading axis."""
    n = args[0].shape[0]

    def one(a):
        take = np.minimum(np.arange(a, a + batch_size), n - 1)
        out = _run_batch(tuple(x[take] for x in args), fn, shared)
        return jax.tree.map(lambda o, k=min(batch_size, n - a): np.asarray(o)[:k], out)

    return jax.tree.map(lambda *p: np.concatenate(p), *_threaded(one, range(0, n, batch_size), workers))


def _threaded(fn, items, workers: int) -> list:
    """[fn(i) for i in items], ``workers`` at once in threads, the first alone (so that what it compiles is compiled
    once, then shared by the threads)."""
    parts = [fn(items[0])]
    if len(items) > 1 and workers > 1:
        with ThreadPoolExecutor(min(workers, len(items) - 1)) as pool:
            parts += list(pool.map(fn, items[1:]))
    else:
        parts += [fn(i) for i in items[1:]]
    return parts


def cache_root(cache: str | os.PathLike | None = None) -> Path:
    """The cache's root directory: the argument, else DPE5G_CACHE, else ``DEFAULT_CACHE``."""
    return Path(cache or os.environ.get("DPE5G_CACHE") or DEFAULT_CACHE)


def cache_dir(e: Experiment, cache: str | os.PathLike | None = None) -> Path:
    """The experiment's cache directory: ``<cache root>/<name>-<key>`` (``cache_root``)."""
    return cache_root(cache) / f"{e.name}-{e.key()}"


class ChunkCache:
    """One experiment's results on disk: ``cache_dir(e, cache)`` holds ``experiment.json`` (the config without the
    trial counts, and the key) and one ``.npz`` per chunk of ``chunk_trials`` trials.  Every file is written
    atomically (temporary file + rename), so a killed run leaves whole chunks and at most a stale ``*.tmp``, which
    ``open`` removes (not another live process's: two processes may fill one cache, ``warm``); ``missing`` lists the
    chunks still to compute (resume), ``load`` concatenates them all."""

    def __init__(self, e: Experiment, cache: str | os.PathLike | None = None):
        self.experiment = e
        self.dir = cache_dir(e, cache)
        self.chunks = [(s, min(s + e.chunk_trials, e.n_trials)) for s in range(0, e.n_trials, e.chunk_trials)]

    def path(self, start: int, stop: int) -> Path:
        return self.dir / f"trials-{start:07d}-{stop:07d}.npz"

    def open(self) -> "ChunkCache":
        """Create the directory and its metadata; remove temporary files a killed run left (their chunks are
        recomputed)."""
        self.dir.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(self.dir)
        meta = self.dir / "experiment.json"
        if not meta.exists():
            d = self.experiment.to_dict()
            d.pop("n_trials")
            d.pop("chunk_trials")
            atomic_write(meta, json.dumps({"key": self.dir.name.rsplit("-", 1)[1], "experiment": d}, indent=1,
                                          default=str).encode())
        return self

    def missing(self) -> list[tuple[int, int]]:
        return [c for c in self.chunks if not self.path(*c).exists()]

    def save(self, start: int, stop: int, arrays: dict) -> None:
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        atomic_write(self.path(start, stop), buf.getvalue())

    def load(self, names) -> dict:
        parts = [np.load(self.path(*c)) for c in self.chunks]
        return {k: np.concatenate([p[k] for p in parts]) for k in names}


#: chunk arrays without an SNR axis (every other array is (T, S, ...)); ``_snr_superset_runs`` slices the others
PER_TRIAL_FIELDS = ("ue_xyz", "clock_bias_s", "bs_index", "los")


def _snr_superset_runs(e: Experiment, cache: str | os.PathLike | None = None) -> list[tuple[ChunkCache, list[int]]]:
    """Cached runs of ``e`` at more SNRs: experiments equal to ``e`` in every field but the name and ``snrs_db``,
    whose SNRs include all of ``e``'s, with the same key (code, data and library versions).  Trial t's draws and its
    noise (drawn once, scaled to each SNR) do not depend on the SNR list, so such a run's chunk, sliced to ``e``'s
    SNRs, is ``e``'s chunk (``tests/test_montecarlo.py`` computes both).  Returns [(its cache, index of each of
    ``e``'s SNRs in its list)]."""
    if e.snr_mode == "link_budget":
        return []
    root = cache_root(cache)
    mine = json.loads(json.dumps(e.to_dict(), default=str))
    out = []
    for meta in sorted(root.glob("*/experiment.json")) if root.is_dir() else []:
        try:
            d = json.loads(meta.read_text())["experiment"]
        except (OSError, ValueError, KeyError):
            continue  # a folder being written, or not ours: not a source
        if not isinstance(d, dict) or set(d) != set(mine) - {"n_trials", "chunk_trials"}:
            continue
        if any(d[k] != mine[k] for k in d if k not in ("name", "snrs_db")):
            continue
        snrs = [float(v) for v in d["snrs_db"]]
        if tuple(snrs) == tuple(e.snrs_db) or not set(e.snrs_db) <= set(snrs):
            continue
        other = dataclasses.replace(e, name=str(d["name"]), snrs_db=tuple(snrs))
        if cache_dir(other, cache) == meta.parent:  # the same code, data and versions
            out.append((ChunkCache(other, cache), [snrs.index(v) for v in e.snrs_db]))
    return out


def _sliced_chunk(path: Path, snr_index: list[int]) -> dict:
    """A chunk of a run at more SNRs, its (T, S, ...) arrays restricted to the SNRs ``snr_index``."""
    with np.load(path) as z:
        return {k: z[k] if k in PER_TRIAL_FIELDS else np.take(z[k], snr_index, axis=1) for k in z.files}


class _ChunkRunner:
    """The compiled computation of a chunk of trials: OTDoA step 1 and its convex fixes (when the experiment asks),
    then the DPE fixes; built on first use (compiling is the slow part) and shared by every chunk of a run."""

    def __init__(self, e: Experiment):
        self.e = e
        self.dep = e.load_deployment()
        self.bnb = e.search.method == "bnb"
        if self.bnb:  # two parts (``_bnb_prep_fn``): the trial's draws and correlograms, then a fix per (SNR, M)
            self.prep = _compiled_step_fn(_bnb_prep_fn, _window_free(e), _deployment_digest(e))
            self.fix = _bnb_fix_fn(_fix_config(e), tuple(e.m_values))
        else:
            self.fn = _compiled_trial_fn(_window_free(e), _deployment_digest(e))
        plain = dataclasses.replace(e, name="", seed=0, n_trials=1, chunk_trials=1)  # what the draws depend on
        self.toa_fn = _compiled_step_fn(_toa_fn, plain, _deployment_digest(e)) if e.otdoa else None
        self.prior_fn = _compiled_step_fn(_prior_fn, plain, _deployment_digest(e)) if e.centring == "prior" else None
        self.window = jnp.asarray(_receiver_window(e)) if self.bnb else None
        # one compiled OTDoA problem per M, built once per run (``otdoa.Solver`` reads cvxpy's data map when built)
        self.solvers = {m: otdoa.Solver(m) for m in e.m_values} if e.otdoa else None

    def __call__(self, start: int, stop: int, batch_size: int, workers: int = 1) -> dict:
        e = self.e
        keys = np.asarray(_trial_keys(e.seed, start, stop))
        if not e.otdoa:
            return self._dpe(keys, None, batch_size, workers)
        # step 1 on the same signals (regenerated from the same keys), then the convex fixes, in pieces: the fixes of
        # piece k+1 (Python, one core) are solved while the DPE of piece k runs (XLA, the GIL released)
        toas, ue, idx = _run_chunk((keys,), self.toa_fn, batch_size, workers=workers)
        n = stop - start
        step = max(-(-n // self.OTDOA_PIECES), 1)
        ots, dpes = [], []
        with ThreadPoolExecutor(1) as background:
            for a in range(0, n, step):
                sl = slice(a, min(a + step, n))
                ot = _otdoa_fixes(e, self.dep, toas[sl], ue[sl], idx[sl], self.solvers)
                ext = _otdoa_centers(e, self.dep, ot, idx[sl]) if e.centring == "otdoa" else None
                ots.append(ot)
                dpes.append(background.submit(self._dpe, keys[sl], ext, batch_size, workers))
            dpes = [f.result() for f in dpes]
        return {k: np.concatenate([p[k] for p in dpes]) for k in dpes[0]} | {
            k: np.concatenate([p[k] for p in ots]) for k in ots[0]}

    #: pieces of a chunk whose OTDoA fixes and DPE overlap (speed only: every trial is computed on its own)
    OTDOA_PIECES = 4

    def _dpe(self, keys, ext, batch_size: int, workers: int) -> dict:
        """The DPE fixes of trials ``keys``; ext (T, S, J, 4) the window centres of centring "otdoa" (else None)."""
        e = self.e
        if ext is None:
            ext = np.zeros((len(keys), e.n_snr, len(e.m_values), 4))
        if e.centring == "prior":
            ext[:] = _run_chunk((keys,), self.prior_fn, batch_size, workers=workers)[:, None, None, :]
        if self.bnb:
            return self._bnb(keys, ext, workers)
        return _run_chunk((keys, ext), self.fn, batch_size, workers=workers)

    def _bnb(self, keys, ext, workers: int) -> dict:
        """The certified search's trials, one at a time (its loops run as long as the slowest trial of a batch needs,
        so it is not batched; ``workers`` trials at once, in threads, the first alone so that each program is
        compiled once): ``_bnb_prep_fn``, then ``_bnb_fix_fn``.  Returns ``_trial_fn``'s dict."""

        def one(i):
            trial, bs, centers, sls, starts = self.prep(keys[i], self.window, ext[i])
            r = {k: np.asarray(v) for k, v in self.fix(bs, centers, sls, starts).items()}  # (S, J, ...)
            trial = {k: np.asarray(v) for k, v in trial.items()}
            bias, err = (np.asarray(a) for a in _score(r["q"], trial["ue_xyz"]))
            return trial | {"est_xyz": r["q"][..., :3], "est_bias_s": bias, "error_m": err,
                            "center_xyz": np.asarray(centers)[..., :3], "edge": r["edge"], "gap": r["gap"],
                            "certified": r["certified"]}

        parts = _threaded(one, range(len(keys)), workers)
        return {k: np.stack([p[k] for p in parts]) for k in parts[0]}


#: trials vmapped together by ``run``, per search method (speed only; results do not depend on it): the grid search
#: runs the same steps for every trial and gains from batching; the certified search's loops run as long as the
#: slowest trial of a batch needs, so its fixes run one trial at a time whatever the batch size
#: (``_ChunkRunner._bnb``), and so do its experiments' OTDoA step 1 and prior centres
BATCH_SIZE = {"grid": 2, "bnb": 1}


def default_workers() -> int:
    """Batches ``run`` computes at once by default: DPE5G_WORKERS if set, else the CPUs this process may use."""
    env = os.environ.get("DPE5G_WORKERS")
    if env is not None:
        try:
            return _checks.integer("DPE5G_WORKERS", int(env), 1, 256)
        except ValueError:
            raise ValueError(f"DPE5G_WORKERS must be an integer in [1, 256], got {env!r}") from None
    return max(len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1), 1)


def run(e: Experiment, cache: str | os.PathLike | None = None, progress: bool = True,
        batch_size: int | None = None, reverse: bool = False, workers: int | None = None) -> Results:
    """Run (or resume, or load) an experiment; returns its ``Results``.

    Chunks already in the cache (``ChunkCache``) are loaded, the others computed and written as they finish; a chunk
    that another process wrote meanwhile is read, not computed again, and a chunk that a cached run of the same
    experiment at more SNRs holds is sliced from it (``_snr_superset_runs``).  progress : a tqdm bar with ETA on stderr.
    batch_size : trials vmapped together (memory/speed only; results do not depend on it; the certified search's
    fixes run one trial at a time); None: ``BATCH_SIZE`` of the experiment's search method.  reverse : compute the
    missing chunks last first (``warm`` does, so that a process filling the cache beside one that runs forward meets
    it in the middle instead of repeating its chunks).
    workers : batches of a chunk computed at once, in threads (speed only; results do not depend on it); None:
    ``default_workers()``.
    """
    _checks.require_x64()
    batch_size = BATCH_SIZE[e.search.method] if batch_size is None else batch_size
    _checks.integer("batch_size", batch_size, 1, 4096)
    workers = default_workers() if workers is None else _checks.integer("workers", workers, 1, 256)
    e.load_deployment()  # validates m_values against the deployment before any work
    store = ChunkCache(e, cache).open()
    if os.environ.get("DPE5G_RUN_LOG"):  # the book build records what its chapters run (tests/test_warm.py)
        with open(os.environ["DPE5G_RUN_LOG"], "a") as f:
            f.write(json.dumps({"run": store.dir.name, "n_trials": e.n_trials}) + "\n")
    todo = store.missing()
    bar = None
    if todo and progress:
        from tqdm import tqdm

        bar = tqdm(total=e.n_trials, initial=e.n_trials - sum(b - a for a, b in todo), desc=f"{e.name} trials",
                   unit="trial", file=sys.stderr, dynamic_ncols=True)
    runner = None
    supersets = _snr_superset_runs(e, cache) if todo else []
    try:
        for start, stop in (todo[::-1] if reverse else todo):
            if not store.path(start, stop).exists():  # (another process may have written it since `missing`)
                src = next(((c, ix) for c, ix in supersets if c.path(start, stop).exists()), None)
                if src is not None:  # a run at more SNRs holds these trials
                    store.save(start, stop, _sliced_chunk(src[0].path(start, stop), src[1]))
                else:
                    runner = runner or _ChunkRunner(e)
                    store.save(start, stop, runner(start, stop, batch_size, workers))
            if bar is not None:
                bar.update(stop - start)
    finally:
        if bar is not None:
            bar.close()
    return Results(e, **store.load(Results.FIELDS + (Results.OTDOA_FIELDS if e.otdoa else ())))


def _otdoa_fixes(e: Experiment, dep: deployment.Deployment, toas: np.ndarray, ue: np.ndarray, idx: np.ndarray,
                 solvers: dict) -> dict:
    """OTDoA fixes (cvxpy, one compiled problem per M: ``solvers`` {M: ``otdoa.Solver``}) from the chunk's ToAs
    (T, S, D, I) of every detector, the true UE positions (T, 3) (for the error only) and the nearest BSs' indices
    (T, I); flagged, never dropped."""
    n_t, n_s, n_d = toas.shape[:3]
    xyz = np.full((n_t, n_s, n_d, len(e.m_values), 3), np.nan)
    ok = np.zeros((n_t, n_s, n_d, len(e.m_values)), dtype=bool)
    for t in range(n_t):
        for j, m in enumerate(e.m_values):
            bs = dep.bs_xyz[idx[t, :m]]
            for s in range(n_s):
                for k in range(n_d):
                    f = solvers[m].solve(bs, toas[t, s, k, :m], float(ue[t, 2]))
                    xyz[t, s, k, j], ok[t, s, k, j] = f.xyz, f.ok
    err = np.linalg.norm(xyz[..., :2] - ue[:, None, None, None, :2], axis=-1)
    return {"otdoa_toa_s": toas, "otdoa_xyz": xyz, "otdoa_error_m": err, "otdoa_ok": ok}


def _otdoa_centers(e: Experiment, dep: deployment.Deployment, ot: dict, idx: np.ndarray) -> np.ndarray:
    """Centring "otdoa": the window centre of each (trial, SNR, M) is the OTDoA fix of detector ``toa_method`` at
    the known UE height with c δt = 0; where that fix is not finite (solver failure), the centroid of the M BSs
    used (known to the receiver).  Returns (T, S, J, 4) metres."""
    k = OTDOA_DETECTORS.index(e.toa_method)
    xyz = ot["otdoa_xyz"][:, :, k]  # (T, S, J, 3)
    out = np.zeros(xyz.shape[:3] + (4,))
    out[..., :3] = xyz
    out[..., 2] = dep.ue_height_m
    bad = ~np.all(np.isfinite(xyz), axis=-1)
    for t, s, j in zip(*np.nonzero(bad)):
        out[t, s, j, :2] = dep.bs_xyz[idx[t, : e.m_values[j]], :2].mean(axis=0)
    return out
