"""3GPP TR 38.901 tapped-delay-line (TDL) channels, eqs. (1)–(2) of the paper.

Eq. (1): h(τ, t) = Σ_l h_l(t) δ(τ - τ_l).  The system is static (paper, Section II-B), so h_l(t) = h_l within a
symbol: each Rayleigh tap is one draw of CN(0, P_l); the LoS tap of TDL-D/E is a specular component of power P_l with
a uniformly random phase.  Eq. (2): τ_l = τ_l,normalized × DS_desired.

The five tables are TR 38.901 V16/V17 Tables 7.7.2-1 (TDL-A) … 7.7.2-5 (TDL-E), transcribed digit for digit.  In
TDL-D/E the first tap appears twice at delay 0: once as the specular LoS path and once as a Rayleigh tap; their dB
difference is the table's K-factor (13.3 dB for TDL-D, 22 dB for TDL-E).

Units: delays in seconds, powers linear (sum 1) unless a name says ``_db``.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..common import _checks
from .nr import PAPER, Numerology


@dataclass(frozen=True)
class TDLTable:
    """One TR 38.901 TDL table: normalized delays (unitless, DS = 1) and powers in dB, tap by tap.

    Attributes
    ----------
    name : str
        The profile, "TDL-A" … "TDL-E".
    table : str
        Its source, e.g. "TR 38.901 Table 7.7.2-3".
    delays_norm : tuple of float (L,)
        Normalized delays τ_l,normalized (unitless, DS = 1).
    powers_db : tuple of float (L,)
        Tap powers, dB.
    los : bool
        True: entry 0 is the specular LoS component, entry 1 the Rayleigh part of the same tap (TDL-D/E).
    """

    name: str
    table: str
    delays_norm: tuple[float, ...]
    powers_db: tuple[float, ...]
    los: bool  # True: entry 0 is the specular LoS component, entry 1 the Rayleigh part of the same tap

    @property
    def k_factor_db(self) -> float | None:
        """K-factor of the table (LoS power over the Rayleigh part of the first tap) in dB; None for NLoS tables."""
        return self.powers_db[0] - self.powers_db[1] if self.los else None


TDL_A = TDLTable(
    "TDL-A",
    "TR 38.901 Table 7.7.2-1",
    (0.0000, 0.3819, 0.4025, 0.5868, 0.4610, 0.5375, 0.6708, 0.5750, 0.7618, 1.5375, 1.8978, 2.2242,
     2.1718, 2.4942, 2.5119, 3.0582, 4.0810, 4.4579, 4.5695, 4.7966, 5.0066, 5.3043, 9.6586),
    (-13.4, 0.0, -2.2, -4.0, -6.0, -8.2, -9.9, -10.5, -7.5, -15.9, -6.6, -16.7,
     -12.4, -15.2, -10.8, -11.3, -12.7, -16.2, -18.3, -18.9, -16.6, -19.9, -29.7),
    False,
)  # fmt: skip

TDL_B = TDLTable(
    "TDL-B",
    "TR 38.901 Table 7.7.2-2",
    (0.0000, 0.1072, 0.2155, 0.2095, 0.2870, 0.2986, 0.3752, 0.5055, 0.3681, 0.3697, 0.5700, 0.5283,
     1.1021, 1.2756, 1.5474, 1.7842, 2.0169, 2.8294, 3.0219, 3.6187, 4.1067, 4.2790, 4.7834),
    (0.0, -2.2, -4.0, -3.2, -9.8, -1.2, -3.4, -5.2, -7.6, -3.0, -8.9, -9.0,
     -4.8, -5.7, -7.5, -1.9, -7.6, -12.2, -9.8, -11.4, -14.9, -9.2, -11.3),
    False,
)  # fmt: skip

TDL_C = TDLTable(
    "TDL-C",
    "TR 38.901 Table 7.7.2-3",
    (0.0, 0.2099, 0.2219, 0.2329, 0.2176, 0.6366, 0.6448, 0.6560, 0.6584, 0.7935, 0.8213, 0.9336,
     1.2285, 1.3083, 2.1704, 2.7105, 4.2589, 4.6003, 5.4902, 5.6077, 6.3065, 6.6374, 7.0427, 8.6523),
    (-4.4, -1.2, -3.5, -5.2, -2.5, 0.0, -2.2, -3.9, -7.4, -7.1, -10.7, -11.1,
     -5.1, -6.8, -8.7, -13.2, -13.9, -13.9, -15.8, -17.1, -16.0, -15.7, -21.6, -22.8),
    False,
)  # fmt: skip

TDL_D = TDLTable(
    "TDL-D",
    "TR 38.901 Table 7.7.2-4",
    (0.0, 0.0, 0.035, 0.612, 1.363, 1.405, 1.804, 2.596, 1.775, 4.042, 7.937, 9.424, 9.708, 12.525),
    (-0.2, -13.5, -18.8, -21.0, -22.8, -17.9, -20.1, -21.9, -22.9, -27.8, -23.6, -24.8, -30.0, -27.7),
    True,
)  # fmt: skip

TDL_E = TDLTable(
    "TDL-E",
    "TR 38.901 Table 7.7.2-5",
    (0.0, 0.0, 0.5133, 0.5440, 0.5630, 0.5440, 0.7112, 1.9092, 1.9293, 1.9589, 2.6426, 3.7136, 5.4524,
     12.0034, 20.6519),
    (-0.03, -22.03, -15.8, -18.1, -19.8, -22.9, -22.4, -18.6, -20.8, -22.6, -22.3, -25.6, -20.2,
     -29.8, -29.2),
    True,
)  # fmt: skip

#: The five profiles by short name "A" … "E".
TABLES: dict[str, TDLTable] = {t.name[-1]: t for t in (TDL_A, TDL_B, TDL_C, TDL_D, TDL_E)}

#: Largest delay spread accepted, in seconds.  TR 38.901 Table 7.7.3-1 goes up to 1000 ns ("very long"); anything
#: above 10 µs is almost certainly a value in nanoseconds passed as seconds.
MAX_DELAY_SPREAD_S = 10e-6
#: the smallest delay spread accepted, s: a tenth of TR 38.901's smallest tabulated one (10 ns); below it a TDL
#: channel is a single path, and a smaller value is most likely a unit mistake
MIN_DELAY_SPREAD_S = 1e-9


@dataclass(frozen=True)
class TDLProfile:
    """A TDL table scaled to a delay spread: the average power delay profile the taps are drawn from.

    Attributes
    ----------
    name, table : str
        As ``TDLTable``.
    delay_spread_s : float
        The delay spread DS_desired it is scaled to, seconds.
    k_factor_db : float or None
        K-factor in dB (TDL-D/E); None for NLoS profiles.
    delays_s : numpy.ndarray float (L,)
        Tap delays in seconds, eq. (2).
    powers : numpy.ndarray float (L,)
        Linear mean tap powers, summing to 1.
    los : numpy.ndarray bool (L,)
        True for the specular LoS component (TDL-D/E entry 0).
    """

    name: str
    table: str
    delay_spread_s: float
    k_factor_db: float | None
    delays_s: np.ndarray
    powers: np.ndarray
    los: np.ndarray

    @property
    def n_taps(self) -> int:
        """Number of entries L."""
        return int(self.delays_s.size)

    @property
    def powers_db(self) -> np.ndarray:
        """Mean tap powers in dB, shape (L,)."""
        return 10.0 * np.log10(self.powers)

    def pdp_db(self) -> np.ndarray:
        """Normalized power delay profile, relative to the strongest entry.

        Returns
        -------
        numpy.ndarray float (L,)
            Tap powers in dB, 0 dB for the strongest.
        """
        return 10.0 * np.log10(self.powers / self.powers.max())


def check_delay_spread(delay_spread_s: float) -> float:
    """Validate a delay spread in seconds: a finite number in [``MIN_DELAY_SPREAD_S``, ``MAX_DELAY_SPREAD_S``].

    Parameters
    ----------
    delay_spread_s : float
        The delay spread, seconds.

    Returns
    -------
    float
        The delay spread, seconds.

    Raises
    ------
    ValueError
        Outside the range; the message says what the value looks like: nanoseconds typed as seconds (65 → 65e-9), or
        seconds far above any TR 38.901 delay spread.
    """
    ds = _checks.finite("delay_spread_s", delay_spread_s)
    if MIN_DELAY_SPREAD_S <= ds <= MAX_DELAY_SPREAD_S:
        return ds
    head = (f"delay_spread_s={ds:g} s is outside the allowed range [{MIN_DELAY_SPREAD_S:g}, {MAX_DELAY_SPREAD_S:g}] "
            f"s")
    if ds <= 0:
        raise ValueError(f"{head}; a delay spread is positive — pass seconds, e.g. 65e-9")
    if ds < MIN_DELAY_SPREAD_S:
        raise ValueError(f"{head}; TR 38.901 delay spreads are 10 ns to a few µs — pass seconds, e.g. 65e-9")
    if 1.0 <= ds <= MAX_DELAY_SPREAD_S * 1e9:  # 1 ns … 10 µs written in nanoseconds
        raise ValueError(f"{head}; {ds:g} looks like nanoseconds — pass seconds: {ds:g} ns is {ds:g}e-9")
    raise ValueError(f"{head}; TR 38.901 delay spreads are 10 ns to a few µs — pass seconds, e.g. 65e-9")


def rms_delay_spread(delays_s, powers) -> float:
    """RMS delay spread sqrt(Σ P τ² / Σ P - (Σ P τ / Σ P)²) of a power delay profile, in the delays' unit.

    This is the second central moment used by TR 38.901; the paper's text calls the span between the first and
    the last arrival the "RMS delay spread", which it is not (see the errata in the book).

    Parameters
    ----------
    delays_s : float (L,)
        Delays, seconds (or any unit), in [0, 1e6].
    powers : float (L,)
        Linear powers, non-negative with a positive sum (normalized here).

    Returns
    -------
    float
        The RMS delay spread, in the delays' unit.

    Raises
    ------
    ValueError
        Shapes that are not 1-D of equal length, or powers negative or summing to 0.
    """
    _checks.values_in_range("delays_s", delays_s, 0.0, 1e6, "(the delays' unit)")
    _checks.values_in_range("powers", powers, 0.0, np.inf, "(linear)")
    d = np.asarray(delays_s, dtype=np.float64)
    p = np.asarray(powers, dtype=np.float64)
    if d.shape != p.shape or d.ndim != 1 or d.size == 0:
        raise ValueError(f"delays_s and powers must be 1-D of equal length, got shapes {d.shape} and {p.shape}")
    if np.any(p < 0) or p.sum() <= 0:
        raise ValueError("powers must be non-negative with a positive sum")
    p = p / p.sum()
    mean = float(np.sum(p * d))
    return float(np.sqrt(max(np.sum(p * d * d) - mean * mean, 0.0)))


#: what the delay spread a profile is scaled to means: "rms" — TR 38.901's RMS delay spread (eq. (2), the paper's
#: figures' captions and Table I); "span" — the time between the earliest and the latest tap, as the paper's text
#: defines DS_desired below eq. (2) (a reading the readings table of the reproduction chapter tries)
DELAY_SPREAD_DEFS = ("rms", "span")


def tdl_profile(name: str, delay_spread_s: float, k_factor_db: float | None = None,
                definition: str = "rms") -> TDLProfile:
    """Scale TR 38.901 TDL-``name`` to ``delay_spread_s`` seconds (eq. (2)) with unit total power.

    Parameters
    ----------
    name : str
        "A" … "E" (or "TDL-A" … "TDL-E"), TR 38.901 Tables 7.7.2-1 … 7.7.2-5.
    delay_spread_s : float
        Desired RMS delay spread DS_desired in seconds (the paper: 65e-9, UMi street canyon short).
    k_factor_db : float or None
        TDL-D/E only, dB in [-30, 60].  None keeps the table's K (13.3 dB for TDL-D, the paper's value; 22 dB for
        TDL-E).  Otherwise TR 38.901 §7.7.6: the Rayleigh taps are shifted by K_model - K_desired dB, powers
        renormalized, and the normalized delays divided by the new profile's RMS spread so the scaled profile still
        has DS_desired.
    definition : str
        One of ``DELAY_SPREAD_DEFS``: ``"rms"`` (TR 38.901), the profile's RMS delay spread is ``delay_spread_s``;
        ``"span"`` (the paper's text), its last tap comes ``delay_spread_s`` after the first (the normalized delays
        divided by the largest; TDL-C's taps then span 65 ns instead of 562 ns).

    Returns
    -------
    TDLProfile
        Its delays_s, powers, los have shape (L,), L = 23, 23, 24, 14, 15 entries for A … E.

    Raises
    ------
    ValueError
        An unknown profile or definition, a delay spread out of range (``check_delay_spread``), or a K-factor out of
        range or given for an NLoS profile.
    """
    key = str(name).upper().removeprefix("TDL-").removeprefix("TDL")
    if key not in TABLES:
        raise ValueError(f"profile must be one of A, B, C, D, E (TR 38.901 TDL-A…E); got {name!r}")
    tab = TABLES[key]
    ds = check_delay_spread(delay_spread_s)
    _checks.one_of("definition", definition, DELAY_SPREAD_DEFS)
    delays_norm = np.asarray(tab.delays_norm, dtype=np.float64)
    powers_db = np.asarray(tab.powers_db, dtype=np.float64)
    los = np.zeros(delays_norm.size, dtype=bool)
    k_out = None
    if tab.los:
        los[0] = True
        k_out = tab.k_factor_db
        if k_factor_db is not None:
            k_des = _checks.in_range("k_factor_db", k_factor_db, -30.0, 60.0, "dB")
            powers_db = powers_db.copy()
            powers_db[1:] += tab.k_factor_db - k_des
            p = 10 ** (powers_db / 10)
            delays_norm = delays_norm / rms_delay_spread(delays_norm, p)
            k_out = k_des
    elif k_factor_db is not None:
        raise ValueError(f"k_factor_db applies to the LoS profiles D and E only; profile {tab.name} is NLoS")
    powers = 10 ** (powers_db / 10)
    powers = powers / powers.sum()
    if definition == "span":
        delays_norm = delays_norm / delays_norm.max()
    return TDLProfile(tab.name, tab.table, ds, k_out, delays_norm * ds, powers, los)


def draw_gains(profile: TDLProfile, key: jax.Array) -> jax.Array:
    """One realisation of the complex tap gains h_l of eq. (1).

    Rayleigh taps: h_l ~ CN(0, P_l).  LoS specular tap: √P_l e^{jφ}, φ ~ U[0, 2π).  ``E Σ|h_l|² = 1``.

    Parameters
    ----------
    profile : TDLProfile
        The power delay profile.
    key : jax PRNG key
        The random key.

    Returns
    -------
    jax.Array complex (L,)
        The gains h_l.
    """
    k_ray, k_phi = jax.random.split(key)
    p = jnp.asarray(profile.powers)
    z = jax.random.normal(k_ray, (profile.n_taps, 2)) @ jnp.array([1.0, 1j])
    ray = jnp.sqrt(p / 2) * z
    spec = jnp.sqrt(p) * jnp.exp(2j * jnp.pi * jax.random.uniform(k_phi, (profile.n_taps,)))
    return jnp.where(jnp.asarray(profile.los), spec, ray)


def frequency_response(gains, delays_s, num: Numerology = PAPER) -> jax.Array:
    """H_k = Σ_l h_l exp(-j 2π k Δf τ_l) on FFT bins k = 0 … N-1, the channel part of eqs. (5)–(6).

    Fractional delays are exact here: no rounding of τ_l to the sample grid.

    Parameters
    ----------
    gains : complex (..., L)
        Tap gains h_l.
    delays_s : float (..., L)
        Tap delays τ_l, seconds.
    num : Numerology
        The numerology (``nr.PAPER`` by default).

    Returns
    -------
    jax.Array complex (..., N)
        H_k.
    """
    k = jnp.arange(num.n_fft)
    phase = jax.lax.complex(*(f(-2 * jnp.pi * num.scs_hz * jnp.asarray(delays_s)[..., :, None] * k)
                              for f in (jnp.cos, jnp.sin)))  # e^{-j2πkΔfτ_l}, as ``signal.unit_phasor``
    return jnp.einsum("...l,...lk->...k", jnp.asarray(gains), phase)


def sampled_cir(gains, delays_s, num: Numerology = PAPER) -> jax.Array:
    """Realised CIR on the sample grid, h[n] = (1/N) Σ_k H_k e^{j2πkn/N}, n = 0 … N-1.

    The band-limited (periodic-sinc) image of the taps as a receiver sampling at f_s sees it: a tap at an integer
    multiple of T_s lands on one sample with its full gain, a fractional one spreads over its neighbours.

    Parameters
    ----------
    gains, delays_s, num
        As ``frequency_response``.

    Returns
    -------
    jax.Array complex (..., N)
        h[n].
    """
    return jnp.fft.ifft(frequency_response(gains, delays_s, num), axis=-1)
