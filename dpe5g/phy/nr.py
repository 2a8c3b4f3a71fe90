"""NR numerology of the paper's carrier and the downlink positioning reference signal (PRS).

The paper (Section II-B, Table I) uses a 100 MHz carrier with 30 kHz subcarrier spacing and full-band PRS with
QPSK pilots of unit power, "frequency resource pattern not a primary concern".  With a 4096-point FFT this gives

* sampling rate ``f_s = N * scs = 122.88 MHz``, sample period ``T_s = 1/f_s ≈ 8.14 ns``,
  sample spacing ``c * T_s ≈ 2.44 m`` (the paper's "2.44 m between adjacent taps");
* 273 resource blocks, i.e. 3276 active subcarriers (TS 38.101-1 Table 5.3.2-1 for 100 MHz at 30 kHz);
* normal cyclic prefix: 288 samples at this rate (TS 38.211 §5.3.1; the first symbol of each half-subframe has 16
  more), i.e. about 2.34 µs, longer than any excess delay of a TDL profile scaled to 65 ns.

The PRS pilots come from the TS 38.211 §5.2.1 length-31 Gold sequence initialised as in §7.4.1.7.2.  The paper's
simplification, every one of the ``N`` FFT bins carrying a unit-modulus QPSK pilot, is the default
(``pattern="full"``); the standard's pattern of 3276 active subcarriers with a comb is an option
(``pattern="comb"``).  All arrays are in FFT-bin order ``k = 0 … N-1`` as in eq. (3) of the paper.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..common import _checks

#: Speed of light in vacuum, m/s.
C = 299_792_458.0

#: Length of the Gold-sequence warm-up, TS 38.211 §5.2.1.
GOLD_NC = 1600

#: OFDM symbols per slot with normal cyclic prefix.
SYMBOLS_PER_SLOT = 14


@dataclass(frozen=True)
class Numerology:
    """OFDM numerology.  Defaults are the paper's carrier: 100 MHz, 30 kHz SCS, N = 4096, 273 RB, normal CP.

    Attributes
    ----------
    scs_hz : float
        Subcarrier spacing Δf in Hz: 15, 30, 60, 120 or 240 kHz.
    n_fft : int
        FFT size N (number of subcarriers of eq. (3)), 8 to 65536.
    n_rb : int
        Number of resource blocks of 12 subcarriers in the carrier, 1 to 275, with 12 n_rb ≤ N.

    Raises
    ------
    ValueError
        A field outside its range.
    """

    scs_hz: float = 30e3
    n_fft: int = 4096
    n_rb: int = 273

    def __post_init__(self) -> None:
        _checks.one_of("scs_hz", float(self.scs_hz), [15e3, 30e3, 60e3, 120e3, 240e3])
        _checks.integer("n_fft", self.n_fft, 8, 1 << 16)
        _checks.integer("n_rb", self.n_rb, 1, 275)
        if 12 * self.n_rb > self.n_fft:
            raise ValueError(f"n_rb must satisfy 12*n_rb <= n_fft={self.n_fft}, got n_rb={self.n_rb}")

    @property
    def mu(self) -> int:
        """Numerology index μ, Δf = 15 kHz · 2^μ."""
        return int(round(np.log2(self.scs_hz / 15e3)))

    @property
    def sample_rate_hz(self) -> float:
        """f_s = N Δf in Hz (122.88 MHz for the paper)."""
        return self.n_fft * self.scs_hz

    @property
    def sample_period_s(self) -> float:
        """T_s = T_u / N in seconds."""
        return 1.0 / self.sample_rate_hz

    @property
    def sample_spacing_m(self) -> float:
        """Distance light travels in one sample, c T_s, in metres (≈ 2.44 m for the paper)."""
        return C / self.sample_rate_hz

    @property
    def useful_symbol_s(self) -> float:
        """T_u = 1/Δf in seconds."""
        return 1.0 / self.scs_hz

    @property
    def n_active(self) -> int:
        """Active subcarriers, 12 per resource block (3276 for 273 RB)."""
        return 12 * self.n_rb

    @property
    def bandwidth_occupied_hz(self) -> float:
        """Occupied bandwidth of the active subcarriers in Hz."""
        return self.n_active * self.scs_hz

    @property
    def cp_samples(self) -> int:
        """Normal CP length in samples, 144 κ 2^-μ T_c (TS 38.211 §5.3.1) at this FFT size."""
        return int(round(144 * self.n_fft / 2048))

    @property
    def cp_s(self) -> float:
        """Normal CP duration T_CP in seconds."""
        return self.cp_samples * self.sample_period_s

    @property
    def slots_per_frame(self) -> int:
        """Slots per 10 ms frame, 10 · 2^μ."""
        return 10 * 2**self.mu


#: The paper's carrier.
PAPER = Numerology()


def gold_sequence(c_init: int, length: int) -> np.ndarray:
    """Pseudo-random sequence c(n), n = 0 … length-1, of TS 38.211 §5.2.1.

    * x1(n+31) = (x1(n+3) + x1(n)) mod 2, x1(0) = 1, x1(1..30) = 0;
    * x2(n+31) = (x2(n+3) + x2(n+2) + x2(n+1) + x2(n)) mod 2, x2 initialised with the bits of c_init;
    * c(n) = (x1(n + Nc) + x2(n + Nc)) mod 2, Nc = 1600.

    Parameters
    ----------
    c_init : int
        The initialiser, 0 to 2^31 − 1 (``prs_c_init`` for the PRS).
    length : int
        Number of bits, 0 to 2^24.

    Returns
    -------
    numpy.ndarray uint8 (length,)
        The bits c(n).

    Raises
    ------
    ValueError
        ``c_init`` or ``length`` outside its range.
    """
    c_init = _checks.integer("c_init", c_init, 0, 2**31 - 1)
    length = _checks.integer("length", length, 0, 1 << 24)
    return _gold_cached(c_init, length).copy()


@lru_cache(maxsize=64)
def _gold_cached(c_init: int, length: int) -> np.ndarray:
    total = length + GOLD_NC + 31
    x1 = np.zeros(total, dtype=np.uint8)
    x2 = np.zeros(total, dtype=np.uint8)
    x1[0] = 1
    x2[:31] = [(c_init >> i) & 1 for i in range(31)]
    # The recursions only look 31 steps back, so they can be advanced 28 samples at a time with array slices.
    n = 0
    while n < total - 31:
        step = min(28, total - 31 - n)
        x1[n + 31 : n + 31 + step] = x1[n + 3 : n + 3 + step] ^ x1[n : n + step]
        x2[n + 31 : n + 31 + step] = (
            x2[n + 3 : n + 3 + step] ^ x2[n + 2 : n + 2 + step] ^ x2[n + 1 : n + 1 + step] ^ x2[n : n + step]
        )
        n += step
    return (x1[GOLD_NC : GOLD_NC + length] ^ x2[GOLD_NC : GOLD_NC + length]).astype(np.uint8)


def prs_c_init(prs_id: int, slot: int = 0, symbol: int = 0) -> int:
    """Gold-sequence initialiser of the DL PRS, TS 38.211 §7.4.1.7.2.

    c_init = (2^22 ⌊n_ID/1024⌋ + 2^10 (N_symb^slot n_s + l + 1)(2 (n_ID mod 1024) + 1) + (n_ID mod 1024)) mod 2^31

    Parameters
    ----------
    prs_id : int
        n_ID^PRS, 0 … 4095.
    slot : int
        n_s,f^μ, the slot in the frame, 0 … 159.
    symbol : int
        l, the OFDM symbol in the slot, 0 … 13.

    Returns
    -------
    int
        c_init, in [0, 2^31).

    Raises
    ------
    ValueError
        An argument outside its range.
    """
    prs_id = _checks.integer("prs_id", prs_id, 0, 4095)
    slot = _checks.integer("slot", slot, 0, 159)
    symbol = _checks.integer("symbol", symbol, 0, SYMBOLS_PER_SLOT - 1)
    lo = prs_id % 1024
    v = (2**22) * (prs_id // 1024) + (2**10) * (SYMBOLS_PER_SLOT * slot + symbol + 1) * (2 * lo + 1) + lo
    return v % (2**31)


def qpsk_from_bits(bits: np.ndarray) -> np.ndarray:
    """QPSK symbols r(m) = ((1 - 2 c(2m)) + j (1 - 2 c(2m+1))) / √2 of TS 38.211 §7.4.1.7.2, of unit modulus.

    Parameters
    ----------
    bits : int (2 K,)
        The bits c(n), 0 or 1.

    Returns
    -------
    numpy.ndarray complex (K,)
        The symbols r(m).
    """
    b = np.asarray(bits, dtype=np.float64)
    return ((1 - 2 * b[0::2]) + 1j * (1 - 2 * b[1::2])) / np.sqrt(2.0)


def active_bins(num: Numerology = PAPER) -> np.ndarray:
    """FFT bins of the active subcarriers, in subcarrier order.

    Subcarrier j = 0 … n_active-1 sits at frequency (j - n_active/2) Δf around the carrier, i.e. in FFT bin
    (j - n_active/2) mod N.

    Parameters
    ----------
    num : Numerology
        The numerology (``PAPER`` by default).

    Returns
    -------
    numpy.ndarray int (n_active,)
        The bins.
    """
    j = np.arange(num.n_active)
    return (j - num.n_active // 2) % num.n_fft


def band_bins(num: Numerology = PAPER) -> np.ndarray:
    """The bins of the active subcarriers in the signal model's own convention, bin k the tone at k Δf of eq. (3).

    That convention (k = 0 … N-1, ``dpe5g.phy.signal``: the channel response and the delay phasor e^{-j2πkΔfτ} use
    k Δf) puts the carrier on the contiguous block k = (N - n_active)/2 + j, j = 0 … n_active-1, centred in the
    sampled band with a guard band of (N - n_active)/2 bins at each end.  ``active_bins`` is the same carrier in the
    two-sided FFT layout (negative frequencies at the top), which only a model reading bins k ≥ N/2 as (k - N) Δf may
    use: under eq. (3)'s convention it would split the band in two, 2458 … 4095 Δf and 0 … 1637 Δf, whose
    correlogram has sidelobes a contiguous band does not.

    Parameters
    ----------
    num : Numerology
        The numerology (``PAPER`` by default).

    Returns
    -------
    numpy.ndarray int (n_active,)
        The bins, in subcarrier order.
    """
    return (num.n_fft - num.n_active) // 2 + np.arange(num.n_active)


def prs_symbols(
    prs_id: int,
    num: Numerology = PAPER,
    *,
    pattern: str = "full",
    comb: int = 2,
    comb_offset: int = 0,
    slot: int = 0,
    symbol: int = 0,
) -> np.ndarray:
    """PRS frequency-domain symbols d_{m,k} of one BS for one OFDM symbol, in FFT-bin order k = 0 … N-1.

    Parameters
    ----------
    prs_id : int
        n_ID^PRS, 0 … 4095 (``prs_c_init``).
    num : Numerology
        The numerology (``PAPER`` by default).
    pattern : str
        ``"full"`` (the paper's simplification, default): every bin carries a unit-modulus QPSK pilot, d_k = r(k), so
        D^H D = I as eq. (8) of the paper requires.  ``"comb"`` (TS 38.211 §7.4.3.2.1): only the 3276 active
        subcarriers can carry PRS, every ``comb``-th one starting at ``comb_offset`` (k' = 0 for this symbol); the
        other bins are zero.  Pilots keep unit modulus.
    comb : int
        Comb size for ``"comb"``: 2, 4, 6 or 12.
    comb_offset : int
        First active subcarrier of the comb, 0 … comb − 1.
    slot, symbol : int
        Slot in the frame and OFDM symbol in the slot, as ``prs_c_init``.

    Returns
    -------
    numpy.ndarray complex128 (N,)
        The symbols d_k.

    Raises
    ------
    ValueError
        An argument outside its range or list.
    """
    _checks.one_of("pattern", pattern, ["full", "comb"])
    d = np.zeros(num.n_fft, dtype=np.complex128)
    c_init = prs_c_init(prs_id, slot, symbol)
    if pattern == "full":
        d[:] = qpsk_from_bits(gold_sequence(c_init, 2 * num.n_fft))
        return d
    comb = _checks.integer("comb", comb, 2, 12)
    _checks.one_of("comb", str(comb), ["2", "4", "6", "12"])
    comb_offset = _checks.integer("comb_offset", comb_offset, 0, comb - 1)
    bins = active_bins(num)[comb_offset::comb]

    d[bins] = qpsk_from_bits(gold_sequence(c_init, 2 * bins.size))
    return d


def prs_matrix(prs_ids, num: Numerology = PAPER, **kwargs) -> np.ndarray:
    """Stack the PRS of several BSs.

    Parameters
    ----------
    prs_ids : int (M,)
        The BSs' PRS IDs, each 0 … 4095.
    num : Numerology
        The numerology (``PAPER`` by default).
    **kwargs
        Passed on to ``prs_symbols`` (``pattern``, ``comb``, ``comb_offset``, ``slot``, ``symbol``).

    Returns
    -------
    numpy.ndarray complex (M, N)
        Row m is ``prs_symbols(prs_ids[m], num, **kwargs)``.
    """
    return np.stack([prs_symbols(int(i), num, **kwargs) for i in prs_ids])


#: comb sizes K_comb of the DL PRS (TS 38.211 §7.4.1.7.3)
PRS_COMB_SIZES = (2, 4, 6, 12)
#: numbers of PRS symbols L_PRS in a slot (TS 38.211 §7.4.1.7.3, Rel-16); L_PRS ≥ K_comb and a multiple of it
PRS_SYMBOL_COUNTS = (2, 4, 6, 12)
#: the frequency offset k' of TS 38.211 Table 7.4.1.7.3-1 per comb size, for the PRS symbol l - l_start = 0 … 11
PRS_K_PRIME = {2: (0, 1, 0, 1, 0, 1, 0, 1, 0, 1, 0, 1),
               4: (0, 2, 1, 3, 0, 2, 1, 3, 0, 2, 1, 3),
               6: (0, 3, 1, 4, 2, 5, 0, 3, 1, 4, 2, 5),
               12: (0, 6, 3, 9, 1, 7, 4, 10, 2, 8, 5, 11)}


@dataclass(frozen=True)
class PrsPattern:
    """The DL PRS resource pattern of TS 38.211 §7.4.1.7.3 in one slot: comb size K_comb, L_PRS symbols from l_start.

    It covers the carrier's active subcarriers (3276 for 273 RB, the PRS bandwidth = the carrier).  The comb offset
    k_offset (dl-PRS-ReOffset, 0 … K_comb − 1) is per resource, an argument of the methods: resources with different
    offsets use disjoint REs in every symbol, because k' depends only on the symbol.

    Attributes
    ----------
    comb_size : int
        K_comb, one of ``PRS_COMB_SIZES``.
    n_symbols : int or None
        L_PRS, one of ``PRS_SYMBOL_COUNTS`` and a multiple of K_comb.  None (default): K_comb, the "fully staggered"
        pattern, every active subcarrier carries exactly one PRS RE of the resource.
    start_symbol : int
        l_start, with l_start + L_PRS ≤ 14.

    Raises
    ------
    ValueError
        A field outside its range or list, or L_PRS not a multiple of K_comb.
    """

    comb_size: int = 6
    n_symbols: int | None = None
    start_symbol: int = 0

    def __post_init__(self):
        _checks.one_of("comb_size", self.comb_size, PRS_COMB_SIZES)
        if self.n_symbols is None:
            object.__setattr__(self, "n_symbols", self.comb_size)
        _checks.one_of("n_symbols", self.n_symbols, PRS_SYMBOL_COUNTS)
        if self.n_symbols < self.comb_size or self.n_symbols % self.comb_size:
            raise ValueError(f"n_symbols must be a multiple of comb_size={self.comb_size} (TS 38.211 §7.4.1.7.3), one "
                             f"of {[n for n in PRS_SYMBOL_COUNTS if n % self.comb_size == 0]}; got {self.n_symbols}")
        _checks.integer("start_symbol", self.start_symbol, 0, SYMBOLS_PER_SLOT - self.n_symbols)

    def subcarriers(self, comb_offset: int, num: Numerology = PAPER) -> np.ndarray:
        """Subcarriers k of the resource with comb offset ``comb_offset`` in each of its symbols, TS 38.211 §7.4.1.7.3.

        k = m K_comb + ((k_offset + k') mod K_comb), m = 0, 1, …, counted from the lowest active subcarrier (the PRS
        occupies all n_rb resource blocks).

        Parameters
        ----------
        comb_offset : int
            k_offset, 0 … K_comb − 1.
        num : Numerology
            The numerology (``PAPER`` by default); K_comb must divide its active subcarriers.

        Returns
        -------
        numpy.ndarray int (L_PRS, n_active / K_comb)
            Row i: the subcarriers of symbol l_start + i.

        Raises
        ------
        ValueError
            ``comb_offset`` out of range, or K_comb not dividing the active subcarriers.
        """
        k_comb = self.comb_size
        comb_offset = _checks.integer("comb_offset", comb_offset, 0, k_comb - 1)
        if num.n_active % k_comb:
            raise ValueError(f"comb_size must divide the {num.n_active} active subcarriers, got {k_comb}")
        m = np.arange(num.n_active // k_comb)
        return np.stack([m * k_comb + (comb_offset + PRS_K_PRIME[k_comb][i]) % k_comb
                         for i in range(self.n_symbols)])

    def resource_elements(self, comb_offset: int, num: Numerology = PAPER) -> np.ndarray:
        """The REs of ``subcarriers`` as bins of the signal model.

        ``band_bins``: subcarrier j at bin (N - n_active)/2 + j, the tone at that multiple of Δf in eq. (3).

        Parameters
        ----------
        comb_offset, num
            As ``subcarriers``.

        Returns
        -------
        numpy.ndarray int (L_PRS, n_active / K_comb)
            Row i: the bins of symbol l_start + i.
        """
        return band_bins(num)[self.subcarriers(comb_offset, num)]


def prs_grid(prs_id: int, pattern: PrsPattern, comb_offset: int, num: Numerology = PAPER, slot: int = 0) -> np.ndarray:
    """The PRS of one resource over its L_PRS symbols: a_{k,l} = β r_l(m) on the REs of ``pattern``, zero elsewhere.

    The REs are those of TS 38.211 §7.4.1.7.3, r_l the QPSK sequence of §7.4.1.7.2 initialised for symbol
    l = l_start + i.  β = √(N / n_RE), n_RE the resource's REs in the slot, so that every pattern carries the pilot
    energy of the paper's full-band symbol, ``Σ_{k,l} |a_{k,l}|² = N``: at equal power a link's energy does not
    depend on the comb size, the number of symbols or the offset, and the SNR keeps the meaning of ``dpe5g.phy.signal``
    (pilot energy over N σ²).

    Parameters
    ----------
    prs_id : int
        n_ID^PRS, 0 … 4095.
    pattern : PrsPattern
        The resource pattern.
    comb_offset : int
        The resource's comb offset k_offset, 0 … K_comb − 1.
    num : Numerology
        The numerology (``PAPER`` by default).
    slot : int
        Slot in the frame, 0 … 159.

    Returns
    -------
    numpy.ndarray complex (L_PRS, N)
        Row i for symbol l_start + i, bins in FFT order.
    """
    bins = pattern.resource_elements(comb_offset, num)
    beta = np.sqrt(num.n_fft / bins.size)
    a = np.zeros((pattern.n_symbols, num.n_fft), dtype=np.complex128)
    for i, row in enumerate(bins):
        c = gold_sequence(prs_c_init(prs_id, slot, pattern.start_symbol + i), 2 * row.size)
        a[i, row] = beta * qpsk_from_bits(c)
    return a


def prs_per_subcarrier(prs_id: int, pattern: PrsPattern, comb_offset: int, num: Numerology = PAPER,
                       slot: int = 0) -> np.ndarray:
    """The fully staggered PRS (L_PRS = K_comb) as one pilot per subcarrier: d_k = a_{k,l(k)}.

    a_{k,l(k)} is the pilot of the one symbol l(k) in which the resource has subcarrier k (zero on the guard bins,
    ``band_bins``).  With a static channel the receiver combines the symbols coherently, Σ_l conj(a_{k,l}) Y_{k,l},
    and each subcarrier then holds one RE with its own noise: the L_PRS symbols act as one symbol with pilots d
    (energy N).  Resources with the same offset share every RE, those with different offsets none.

    Parameters
    ----------
    prs_id, pattern, comb_offset, num, slot
        As ``prs_grid``.

    Returns
    -------
    numpy.ndarray complex (N,)
        The pilots d_k.

    Raises
    ------
    ValueError
        ``pattern`` is not fully staggered (L_PRS ≠ K_comb).
    """
    if pattern.n_symbols != pattern.comb_size:
        raise ValueError(f"n_symbols must equal comb_size={pattern.comb_size} for one pilot per subcarrier (each "
                         f"subcarrier in exactly one symbol), got {pattern.n_symbols}")
    return prs_grid(prs_id, pattern, comb_offset, num, slot).sum(axis=0)
