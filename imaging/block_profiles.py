"""What the block kernel (``imaging.backprojection``) needs of each profile at a block's centre, for a group of
profiles at once.

Per (block, profile) the float32 kernel needs, besides its per-pixel loops, a few float64 scalars: the
antennas' vectors to the block centre and their lengths, the centre's bin and phase, how the pixels' range
offsets are formed (``imaging.range_offsets``: one series on the antennas' midpoint, two series, or a
square root) and that form's coefficients. Computed inside the loop over profiles, one profile after the
other, that is a chain of square roots, divisions and branches per (block, profile). Here it is computed
for a group of TABLE_PROFILES profiles before the block's loop over them, in a branch-free loop that LLVM
vectorises over profiles (eight float64 lanes), into a table that loop reads:

``profile_rows``    once per call, what depends on the profiles alone, in a float64 table per group:
                    their antennas, half their TX-RX distance, their reference range and flags: whether
                    the TX is new (not the previous profile's) and whether it is alone (no neighbouring
                    profile shares it);
``block_profile_table``  once per (block, group): TABLE_SIZE float32 values and two int32 ones per
                    profile (the centre's bin ``IBASE`` and the form's ``CODE``).

Each table is one flat array whose rows lie a constant TABLE_PROFILES apart: LLVM checks at run time that
the arrays a loop writes do not overlap those it reads, one check per pair of pointers, and gives up
vectorising beyond eight; rows of a 2-D array (a run-time stride) would each count as a pointer.

A form's code: FORM_FOLDED and FORM_GRADIENT are the midpoint forms (see imaging/range_offsets.py),
FORM_TWO_SERIES both antennas' series in one pass, FORM_RX_SERIES and FORM_RX_ROOT the RX by its series or its
square root after the TX's offsets (stored, and reused by the profiles that share the TX). NEW_TX_OFFSETS is
set where these offsets are to be computed for this profile, TX_SERIES where that is by the series.

Whether a series applies is decided by comparing a distance with ``series_min_distance`` (one bisection per
block), where the loop kernel evaluated ``series_applies`` per profile; the two differ within 1e-7 of that
distance only, where either form is within tolerance.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from imaging.numba_target import prefer_full_width_vectors
from imaging.range_offsets import FOLD_GRADIENT_MAX, series_min_distance

prefer_full_width_vectors()  # before this module's first numba decorator (imaging/numba_target.py)

_TWO_PI = 2.0 * math.pi

# The forms (the code's low three bits) and flags.
FORM_FOLDED, FORM_GRADIENT, FORM_TWO_SERIES, FORM_RX_SERIES, FORM_RX_ROOT = 1, 2, 3, 4, 5
FORM_MASK = 7
NEW_TX_OFFSETS = 8
TX_SERIES = 16

#: Profiles per table. A table's rows lie this many elements apart, a constant, so that LLVM sees one array
#: (its rows a pointer each would be more than it checks for overlap); 64 profiles' table (5.4 KiB) stays in L1.
TABLE_PROFILES = 64
_R = TABLE_PROFILES
# Offsets of the rows of the float32 table (block_profile_table; profile j's value at OFFSET + j).
# The centre's bin (fraction; clamps relative to IBASE) and phase in turns:
FRAC_C, LO, TOP, TURNS_C = 0 * _R, 1 * _R, 2 * _R, 3 * _R
V0, V1, V2 = 4 * _R, 5 * _R, 6 * _R  # the first numerator's vector: the folded midpoint one, 2 (c - m), or 2 u_tx
E0, E1, E2 = 7 * _R, 8 * _R, 9 * _R  # delta's gradient, per pixel (FORM_GRADIENT), else 0
B0, B1, B2 = 10 * _R, 11 * _R, 12 * _R  # 2 u_rx
# The first series' scales: 2 / |c - m|, 1 / |c - m|^2 (midpoint forms), else 1 / |u_tx|, 1 / |u_tx|^2:
SV0, SV1 = 13 * _R, 14 * _R
SB0, SB1 = 15 * _R, 16 * _R  # the RX series' scales: 1/|u_rx|, 1/|u_rx|^2
A_N, A_N2 = 17 * _R, 18 * _R  # |u_tx|, |u_tx|^2 (the TX's square-root form)
B_N, B_N2 = 19 * _R, 20 * _R  # |u_rx|, |u_rx|^2 (the RX's)
TABLE_SIZE = 21 * _R
# Of the int32 table: the centre's bin and the form's code.
IBASE, CODE, INT_TABLE_SIZE = 0 * _R, 1 * _R, 2 * _R
# Of profile_rows' float64 tables, and the flags' values.
TX_X, TX_Y, TX_Z, RX_X, RX_Y, RX_Z = 0 * _R, 1 * _R, 2 * _R, 3 * _R, 4 * _R, 5 * _R
HALF_BASELINE, REFERENCE_RANGE, FLAGS, PROFILE_TABLE_SIZE = 6 * _R, 7 * _R, 8 * _R, 9 * _R
FLAG_NEW_TX, FLAG_TX_ALONE = 1, 2


@numba.njit(nogil=True)
def profile_rows(tx, rx, r_ref, p0, p1):
    """Profiles p0..p1-1 in groups of TABLE_PROFILES, a float64 table per group ([groups, PROFILE_TABLE_SIZE];
    profile p0 + TABLE_PROFILES g + j's TX_X at [g, TX_X + j], and so on): its TX's and RX's x, y, z, half
    their distance, its reference range and flags (FLAG_NEW_TX: the TX is not the
    previous profile's; FLAG_TX_ALONE: nor the next one's either; their sum, as a float). A group's first TX
    counts as new (its offsets are not carried over from another group), and a last one's as not shared
    with the next."""
    n = p1 - p0
    groups = (n + TABLE_PROFILES - 1) // TABLE_PROFILES
    rows = np.zeros((groups, PROFILE_TABLE_SIZE))
    for g in range(groups):
        q0 = p0 + g * TABLE_PROFILES
        q1 = min(q0 + TABLE_PROFILES, p1)
        t = rows[g]
        for p in range(q0, q1):
            j = p - q0
            t[TX_X + j], t[TX_Y + j], t[TX_Z + j] = tx[p, 0], tx[p, 1], tx[p, 2]
            t[RX_X + j], t[RX_Y + j], t[RX_Z + j] = rx[p, 0], rx[p, 1], rx[p, 2]
            h2 = 0.25 * ((tx[p, 0] - rx[p, 0]) ** 2 + (tx[p, 1] - rx[p, 1]) ** 2 + (tx[p, 2] - rx[p, 2]) ** 2)
            t[HALF_BASELINE + j] = math.sqrt(h2)
            t[REFERENCE_RANGE + j] = r_ref[p]
            new_tx = p == q0 or tx[p, 0] != tx[p - 1, 0] or tx[p, 1] != tx[p - 1, 1] or tx[p, 2] != tx[p - 1, 2]
            shared = p + 1 < q1 and tx[p + 1, 0] == tx[p, 0] and tx[p + 1, 1] == tx[p, 1] and tx[p + 1, 2] == tx[p, 2]
            t[FLAGS + j] = (FLAG_NEW_TX if new_tx else 0) + (FLAG_TX_ALONE if new_tx and not shared else 0)
    return rows


@numba.njit(nogil=True)
def block_series_distances(radius):
    """(the least distance at which one antenna's series applies to a block of this radius, the same for the
    midpoint's series, whose folded numerator reaches a radius (1 + FOLD_GRADIENT_MAX / 2) further), by
    bisection (``series_min_distance``): once per block, not per group of profiles (about 2,000 cycles)."""
    return series_min_distance(radius), series_min_distance(radius * (1.0 + 0.5 * FOLD_GRADIENT_MAX))


# error_model="numpy": a division by zero (a block centred on an antenna) gives inf, not a raise: the check
# for one per division keeps LLVM from vectorising the loop. No fastmath, whose
# "no infinities" would allow anything there (and whose reciprocals would round other than the scalar code).
@numba.njit(nogil=True, error_model="numpy", fastmath={"contract"})
def block_profile_table(cx, cy, cz, radius, u_one, u_mid, prof, n, r0, inv_dr, hi, k, tol_m, table, ints):
    """Fill ``table`` [TABLE_SIZE] (float32; profile j's FRAC_C at FRAC_C + j, and so on) and ``ints``
    [INT_TABLE_SIZE] (int32: IBASE, CODE) for the block centred on (cx, cy, cz) with every pixel
    within ``radius`` of it (``block_series_distances``: u_one, u_mid), for the first n profiles of a group
    ``prof`` of ``profile_rows``,
    the kernel's range axis (r0, inv_dr, hi: the last bin position), wavenumber k and midpoint tolerance
    tol_m (MIDPOINT_PHASE_RAD / k, metres).

    The midpoint form's decision is ``imaging.range_offsets.midpoint_form``'s, written without branches."""
    r2 = radius * radius
    for j in range(n):
        ua0, ua1, ua2 = cx - prof[TX_X + j], cy - prof[TX_Y + j], cz - prof[TX_Z + j]
        ub0, ub1, ub2 = cx - prof[RX_X + j], cy - prof[RX_Y + j], cz - prof[RX_Z + j]
        ua2n = ua0 * ua0 + ua1 * ua1 + ua2 * ua2
        ub2n = ub0 * ub0 + ub1 * ub1 + ub2 * ub2
        ua, ub = math.sqrt(ua2n), math.sqrt(ub2n)
        # The block centre's bin and phase in float64; per pixel only what the offset adds, in float32.
        dr_c = ua + ub - prof[REFERENCE_RANGE + j]
        pos_c = (dr_c - r0) * inv_dr + 1.0
        base = np.floor(pos_c)
        table[FRAC_C + j] = np.float32(pos_c - base)
        table[LO + j] = np.float32(-base)
        table[TOP + j] = np.float32(hi - base)
        turns = k * dr_c * (1.0 / _TWO_PI)
        table[TURNS_C + j] = np.float32(turns - np.floor(turns + 0.5))
        ints[IBASE + j] = np.int32(base)
        # The midpoint form (imaging/range_offsets.py, midpoint_form), every branch computed.
        um0, um1, um2 = 0.5 * (ua0 + ub0), 0.5 * (ua1 + ub1), 0.5 * (ua2 + ub2)
        um = math.sqrt(um0 * um0 + um1 * um1 + um2 * um2)
        hb = prof[HALF_BASELINE + j]
        near = um - radius - hb
        inv_a, inv_b, inv_m = 1.0 / ua, 1.0 / ub, 1.0 / um
        e0 = ua0 * inv_a + ub0 * inv_b - 2.0 * um0 * inv_m
        e1 = ua1 * inv_a + ub1 * inv_b - 2.0 * um1 * inv_m
        e2 = ua2 * inv_a + ub2 * inv_b - 2.0 * um2 * inv_m
        e_n = abs(e0) + abs(e1) + abs(e2)
        near2 = near * near
        allowed = tol_m * near2 * near
        delta = 1.5 * r2 * hb * hb
        flags = prof[FLAGS + j]
        alone = flags >= FLAG_TX_ALONE
        midpoint = alone & (um >= u_mid) & (near > 0.0)
        folded = midpoint & (e_n <= FOLD_GRADIENT_MAX) & (2.0 * um * e_n * radius <= near2) & (
            delta + r2 * e_n * (near2 + 0.71 * um * um * e_n) <= allowed)
        gradient = midpoint & (delta <= allowed) & (not folded)
        a_series, b_series = ua >= u_one, ub >= u_one
        two = alone & (not folded) & (not gradient) & a_series & b_series
        form = (FORM_FOLDED if folded else FORM_GRADIENT if gradient else FORM_TWO_SERIES if two
                else FORM_RX_SERIES if b_series else FORM_RX_ROOT)
        new_offsets = (form >= FORM_RX_SERIES) & (flags != 0.0)  # a TX alone is new too
        ints[CODE + j] = form | (NEW_TX_OFFSETS if new_offsets else 0) | (TX_SERIES if a_series else 0)
        on_mid = folded | gradient
        # Each value chosen before its store: a choice around the whole stored value, LLVM made into two
        # stores under complementary masks (``vmaskmovps``, slow on AMD's cores).
        v0 = 2.0 * um0 + (um * e0 if folded else 0.0) if on_mid else 2.0 * ua0
        v1 = 2.0 * um1 + (um * e1 if folded else 0.0) if on_mid else 2.0 * ua1
        v2 = 2.0 * um2 + (um * e2 if folded else 0.0) if on_mid else 2.0 * ua2
        table[V0 + j] = np.float32(v0)
        table[V1 + j] = np.float32(v1)
        table[V2 + j] = np.float32(v2)
        table[E0 + j] = np.float32(e0 if gradient else 0.0)
        table[E1 + j] = np.float32(e1 if gradient else 0.0)
        table[E2 + j] = np.float32(e2 if gradient else 0.0)
        table[B0 + j] = np.float32(2.0 * ub0)
        table[B1 + j] = np.float32(2.0 * ub1)
        table[B2 + j] = np.float32(2.0 * ub2)
        table[SV0 + j] = np.float32(2.0 * inv_m if on_mid else inv_a)
        table[SV1 + j] = np.float32(inv_m * inv_m if on_mid else inv_a * inv_a)
        table[SB0 + j] = np.float32(inv_b)
        table[SB1 + j] = np.float32(inv_b * inv_b)
        table[A_N + j] = np.float32(ua)
        table[A_N2 + j] = np.float32(ua2n)
        table[B_N + j] = np.float32(ub)
        table[B_N2 + j] = np.float32(ub2n)
