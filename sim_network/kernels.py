"""Numba kernels: advance the whole network by many steps in one call, over flat arrays.

One step k (time k·dt to (k+1)·dt), in this order:
1. noise: at the start of each noise window every neuron draws a new current with the
   configured mean and s.d. from its own xoshiro128++ generator (state kept in the
   network), advanced once per window, so the stream depends neither on dt nor on chunking
   (for the Izhikevich model the draw is fused into the update pass of step 4);
2. stimulation: the current of every pulse with start ≤ k < end is summed per neuron;
3. synaptic input due at step k (ring-buffer slot k mod n_slots) is added to v (a voltage jump);
4. the neuron model integrates one step (an Izhikevich neuron's input less its
   spike-frequency adaptation current, plus its slow synaptic current, which takes a share of
   the jump arriving now); threshold crossings are recorded as spikes at step k
   (in index order) and reset;
5. each spike raises its neuron's adaptation current and adds its weights (scaled by
   short-term depression) to the ring slot of step k + delay of each outgoing synapse; STDP,
   if on, updates excitatory weights.
No allocation happens inside; the output arrays have room for at least one full step, and
the kernel returns early (with the number of steps done) when they would overflow.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic, overload

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_M32 = np.uint64(0xFFFFFFFF)
_S32 = np.uint64(32)
# xoshiro128++ (Blackman & Vigna 2018): four uint32 words of state per neuron, all 32 output
# bits usable; only shifts, rotates, adds and xors, so it vectorises eight neurons to a ymm
_U7 = np.uint32(7)
_U25 = np.uint32(25)
_U9 = np.uint32(9)
_U11 = np.uint32(11)
_U21 = np.uint32(21)
_U8 = np.uint32(8)
_U16 = np.uint32(16)
_BYTES_02 = np.uint32(0x00FF00FF)  # bytes 0 and 2 of a word
_M10 = np.uint32(0x3FF)
# Irwin-Hall(4) from the four bytes f_j of one draw: uniforms u_j = (f_j + 0.5) / 256,
# z = (sum u_j - 2)·√3 / √(1 - 2^-16), the last factor making the s.d. of the discrete sum
# exactly 1 (the variance of a uniform on 256 centred cells is (1 - 2^-16)/12)
_IH_SCALE = np.float32(math.sqrt(3.0) / 256.0 / math.sqrt(1.0 - 2.0**-16))
_IH_SHIFT = np.float32((2.0 / 256.0 - 2.0) * math.sqrt(3.0) / math.sqrt(1.0 - 2.0**-16))
# fast-math limited to what lets the update loops vectorise with FMA; no reassociation
_FAST = {"contract", "nnan", "ninf", "nsz"}
V_FLOOR_MV = -100.0
#: an Izhikevich neuron spikes when v reaches this peak (then resets to c)
IZH_V_PEAK_MV = 30.0
#: a Hodgkin-Huxley neuron spikes when v crosses this upward (once per crossing)
HH_SPIKE_THRESHOLD_MV = 0.0
# Neuron state is float32 (halves memory traffic, doubles SIMD width); the Izhikevich update
# uses float32 constants so that it stays in single precision.
STATE_DTYPE = np.float32
_F0 = np.float32(0.0)
_F_PEAK = np.float32(IZH_V_PEAK_MV)
_F_FLOOR = np.float32(V_FLOOR_MV)


@intrinsic
def _prefetch(typingctx, arr, idx):
    """Hint the CPU to fetch the cache line of arr[idx] (llvm.prefetch: read, keep in cache)."""
    sig = types.void(arr, idx)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(
            context, builder, aryty, ary, [args[1]], wraparound=False, boundscheck=False
        )
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.prefetch.p0i8")
        args_ = [builder.bitcast(ptr, i8p), ir.Constant(i32, 0), ir.Constant(i32, 3)]
        builder.call(fn, args_ + [ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, nogil=True, inline="always")
def splitmix64(x):
    """SplitMix64 finaliser: a high-quality 64-bit hash (Steele et al. 2014)."""
    z = x + _GOLDEN
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return z ^ (z >> _S31)


@njit(cache=True, nogil=True)
def seed_noise_state(seed, state):
    """Seed every neuron's noise generator from one 64-bit seed.

    Neuron j's four words are the two halves of the next two SplitMix64 outputs (never all
    zero, the one state xoshiro cannot leave).

    Parameters
    ----------
    seed : uint64
        The network's noise seed.
    state : uint32[4, n]
        Filled in place: the xoshiro128++ state of each neuron.
    """
    x = np.uint64(seed)
    for j in range(state.shape[1]):
        for r in range(2):
            x = splitmix64(x)
            state[2 * r, j] = np.uint32(x & _M32)
            state[2 * r + 1, j] = np.uint32(x >> _S32)
        if state[0, j] == 0 and state[1, j] == 0 and state[2, j] == 0 and state[3, j] == 0:
            state[0, j] = np.uint32(1)


@njit(cache=True, nogil=True, inline="always")
def _xoshiro128pp(a0, a1, a2, a3):
    """One xoshiro128++ step on a state held in four uint32 scalars: (output, new state).

    (Scalars in, scalars out: a helper that takes the state arrays costs reference counting
    per neuron, which keeps the loop from vectorising.)
    """
    t = np.uint32(a0 + a3)
    r = np.uint32(np.uint32(np.uint32(t << _U7) | np.uint32(t >> _U25)) + a0)
    t = np.uint32(a1 << _U9)
    a2 ^= a0
    a3 ^= a1
    a1 ^= a2
    a0 ^= a3
    a2 ^= t
    a3 = np.uint32(np.uint32(a3 << _U11) | np.uint32(a3 >> _U21))
    return r, a0, a1, a2, a3


@njit(cache=True, nogil=True, inline="always")
def _irwin_hall4(r):
    """An Irwin–Hall(4) variate (float32) from the four bytes of the 32-bit draw r.

    The bytes are four uniforms on 256 centred cells, summed (0..1020, by two masked adds),
    centred and scaled to mean 0 and s.d. 1 exactly; bell-shaped (kurtosis 2.7), tails cut
    at ±3.45 s.d.
    """
    pairs = np.uint32(np.uint32(r & _BYTES_02) + np.uint32(np.uint32(r >> _U8) & _BYTES_02))
    total = np.uint32(np.uint32(pairs + np.uint32(pairs >> _U16)) & _M10)
    return np.float32(np.int32(total)) * _IH_SCALE + _IH_SHIFT


@njit(cache=True, nogil=True, fastmath=_FAST)
def fill_noise(noise_cur, state, mean, sd):
    """Draw each neuron's noise current (per-neuron mean and sd arrays) for one window.

    Advances each neuron's xoshiro128++ state (4, n) uint32 by one draw; the variate is
    Irwin–Hall(4) (see `_irwin_hall4`). Each neuron has its own generator, advanced once per
    window, so the stream does not depend on dt or chunking. The Izhikevich update draws the
    same values itself (fused into its pass); this is the standalone form for the other
    models.

    Parameters
    ----------
    noise_cur : float32[n]
        Written: each neuron's current for the window, mean + sd · variate.
    state : uint32[4, n]
        Each neuron's generator, advanced by one draw.
    mean, sd : float32[n]
        Per-neuron mean and standard deviation of the current.
    """
    s0 = state[0]
    s1 = state[1]
    s2 = state[2]
    s3 = state[3]
    for i in range(noise_cur.size):
        r, s0[i], s1[i], s2[i], s3[i] = _xoshiro128pp(s0[i], s1[i], s2[i], s3[i])
        noise_cur[i] = mean[i] + sd[i] * _irwin_hall4(r)


@njit(cache=True, nogil=True, inline="always")
def _vtrap(x, y):
    if abs(x / y) < 1e-6:
        return y * (1.0 - x / y / 2.0)
    return x / (math.exp(x / y) - 1.0)


@njit(cache=True, nogil=True, inline="always")
def _hh_step(vi, m, h, nn, current, p, i, dt):
    """Advance one HH neuron by dt in sub-steps: exponential Euler gates, Euler v."""
    n_sub = int(p[7, i])
    hs = dt / n_sub
    g_na = p[0, i]
    g_k = p[1, i]
    g_l = p[2, i]
    e_na = p[3, i]
    e_k = p[4, i]
    e_l = p[5, i]
    c_m = p[6, i]
    for _ in range(n_sub):
        am = 0.1 * _vtrap(-(vi + 40.0), 10.0)
        bm = 4.0 * math.exp(-(vi + 65.0) / 18.0)
        ah = 0.07 * math.exp(-(vi + 65.0) / 20.0)
        bh = 1.0 / (1.0 + math.exp(-(vi + 35.0) / 10.0))
        an = 0.01 * _vtrap(-(vi + 55.0), 10.0)
        bn = 0.125 * math.exp(-(vi + 65.0) / 80.0)
        sm = am + bm
        sh = ah + bh
        sn = an + bn
        m = am / sm + (m - am / sm) * math.exp(-hs * sm)
        h = ah / sh + (h - ah / sh) * math.exp(-hs * sh)
        nn = an / sn + (nn - an / sn) * math.exp(-hs * sn)
        i_ion = (
            g_na * m * m * m * h * (vi - e_na)
            + g_k * nn * nn * nn * nn * (vi - e_k)
            + g_l * (vi - e_l)
        )
        vi += hs * (current - i_ion) / c_m
    return vi, m, h, nn


@njit(cache=True, nogil=True, fastmath=_FAST, inline="always")
def _izh_one(vi, ui, current, ai, bi, h, c2, c1, c0, dtf):
    """One Euler step of v (already jumped and floored), then u with the new v.

    v + h·(0.04v² + 5v + 140 + I − u) is computed as (c2·v + c1)·v + (h·(I − u) + c0) with
    c2 = 0.04h, c1 = 1 + 5h, c0 = 140h: the same step in two dependent FMAs instead of three.
    """
    vi = (c2 * vi + c1) * vi + (h * (current - ui) + c0)
    return vi, ui + dtf * ai * (bi * vi - ui)


@njit(cache=True, nogil=True, fastmath=_FAST, inline="always")
def _izh_two(vi, ui, current, ai, bi, h, c2, c1, c0, dtf):
    """Izhikevich's two half-steps of v (clipped at the peak between them), then u."""
    hd = h * (current - ui) + c0
    vi = (c2 * vi + c1) * vi + hd
    vi = min(vi, _F_PEAK)
    vi = (c2 * vi + c1) * vi + hd
    return vi, ui + dtf * ai * (bi * vi - ui)


def _with_stim(current, stim_cur, i):
    """current + stim_cur[i], or current when stim_cur is None (no pulse on in this step)."""
    return current if stim_cur is None else current + stim_cur[i]


@overload(_with_stim, inline="always")
def _with_stim_impl(current, stim_cur, i):
    if isinstance(stim_cur, types.NoneType):  # compiled away: no load of a zero array
        return lambda current, stim_cur, i: current
    return lambda current, stim_cur, i: current + stim_cur[i]


def _less_adaptation(current, adapt_a, adapt_g, i):
    """current − a_i·g (the adaptation current), or current when adaptation is off (None)."""
    return current if adapt_a is None else current - adapt_a[i] * adapt_g


@overload(_less_adaptation, inline="always")
def _less_adaptation_impl(current, adapt_a, adapt_g, i):
    if isinstance(adapt_a, types.NoneType):  # compiled away: a culture without adaptation
        return lambda current, adapt_a, adapt_g, i: current
    return lambda current, adapt_a, adapt_g, i: current - adapt_a[i] * adapt_g


def _with_slow(current, slow, gain, decay, jump, i):
    """current + the slow synaptic current after it decays one step and takes this step's
    jump, or current when the slow current is off (None)."""
    if slow is None:
        return current
    slow[i] = slow[i] * decay + gain * jump
    return current + slow[i]


@overload(_with_slow, inline="always")
def _with_slow_impl(current, slow, gain, decay, jump, i):
    if isinstance(slow, types.NoneType):  # compiled away: a culture without it
        return lambda current, slow, gain, decay, jump, i: current

    def impl(current, slow, gain, decay, jump, i):
        x = slow[i] * decay + gain * jump
        slow[i] = x
        return current + x

    return impl


def adaptation_period(decay: float, limit: int = 1024) -> int:
    """Steps between renormalisations of the adaptation amplitudes.

    The largest power of two up to `limit` over which the decay factor stays above 1e-6, so
    that a / g stays well inside float32.

    Parameters
    ----------
    decay : float
        The per-step factor exp(−dt/τ), in (0, 1).
    limit : int

    Returns
    -------
    int
    """
    period = 1
    while period < limit and decay ** (2 * period) >= 1e-6:
        period *= 2
    return period


def adaptation_factors(decay, period: int) -> np.ndarray:
    """decay**j for j = 0..period, by repeated float32 multiplication (the kernel's g).

    Parameters
    ----------
    decay : float32
    period : int
        From `adaptation_period`.

    Returns
    -------
    float32[period + 1]
    """
    g = np.empty(period + 1, dtype=STATE_DTYPE)
    g[0] = 1.0
    for j in range(1, period + 1):
        g[j] = g[j - 1] * STATE_DTYPE(decay)
    return g


@njit(cache=True, nogil=True, fastmath=_FAST)
def _izhikevich_update(
    v, u, a, b, row, noise_cur, noise_state, noise_mean, noise_sd, redraw, stim_cur, scratch,
    dt, n_sub, adapt_a=None, adapt_g=1.0, slow=None, slow_gain=0.0, slow_decay=1.0,
):  # fmt: skip
    """One Izhikevich step for all neurons, branch-free so that it vectorises.

    When `redraw`, each neuron first draws its noise current for the new window (the same
    values as `fill_noise`) in the same pass, which keeps it in registers and touches v, u
    and the generator state once per step. v gets the synaptic jumps due now (floored at
    V_FLOOR_MV so that the quadratic cannot run away from far below rest), then n_sub Euler
    sub-steps (two half-steps at 1 ms, as in Izhikevich 2003), clipped at the 30 mV peak
    between sub-steps; u is then updated with v. The caller scans for the neurons at the
    peak afterwards (counting them here costs more than the scan: it halves the SIMD width).
    `stim_cur` is None when no pulse is on: that variant does not read it at all.
    The adaptation current a_i·g (`adapt_a` float32[n], `adapt_g` float32) is subtracted from
    the input: the loop only reads it (a store per neuron would cost the vectoriser its
    runtime alias checks); `adapt_a` None when adaptation is off (compiled away).
    `slow` (float32[n]) is the slow synaptic current: it decays by `slow_decay`, grows by
    `slow_gain` × the jump arriving now and is added to the input; None when off.
    """
    h = np.float32(dt / n_sub)
    c2 = np.float32(0.04 * dt / n_sub)
    c1 = np.float32(1.0 + 5.0 * dt / n_sub)
    c0 = np.float32(140.0 * dt / n_sub)
    dtf = np.float32(dt)
    s0 = noise_state[0]
    s1 = noise_state[1]
    s2 = noise_state[2]
    s3 = noise_state[3]
    if n_sub == 1:  # dt <= 0.5 ms
        if redraw:
            for i in range(v.size):
                r, s0[i], s1[i], s2[i], s3[i] = _xoshiro128pp(s0[i], s1[i], s2[i], s3[i])
                current = noise_mean[i] + noise_sd[i] * _irwin_hall4(r)
                noise_cur[i] = current
                jump = row[i]
                vi = min(max(v[i] + jump, _F_FLOOR), _F_PEAK)
                row[i] = _F0
                current = _with_stim(_less_adaptation(current, adapt_a, adapt_g, i), stim_cur, i)
                current = _with_slow(current, slow, slow_gain, slow_decay, jump, i)
                v[i], u[i] = _izh_one(vi, u[i], current, a[i], b[i], h, c2, c1, c0, dtf)
        else:
            for i in range(v.size):
                jump = row[i]
                vi = min(max(v[i] + jump, _F_FLOOR), _F_PEAK)
                row[i] = _F0
                current = _less_adaptation(noise_cur[i], adapt_a, adapt_g, i)
                current = _with_stim(current, stim_cur, i)
                current = _with_slow(current, slow, slow_gain, slow_decay, jump, i)
                v[i], u[i] = _izh_one(vi, u[i], current, a[i], b[i], h, c2, c1, c0, dtf)
        return
    if n_sub == 2:  # dt in (0.5, 1] ms: Izhikevich's two half-steps, in one vectorised pass
        if redraw:
            for i in range(v.size):
                r, s0[i], s1[i], s2[i], s3[i] = _xoshiro128pp(s0[i], s1[i], s2[i], s3[i])
                current = noise_mean[i] + noise_sd[i] * _irwin_hall4(r)
                noise_cur[i] = current
                jump = row[i]
                vi = min(max(v[i] + jump, _F_FLOOR), _F_PEAK)
                row[i] = _F0
                current = _with_stim(_less_adaptation(current, adapt_a, adapt_g, i), stim_cur, i)
                current = _with_slow(current, slow, slow_gain, slow_decay, jump, i)
                v[i], u[i] = _izh_two(vi, u[i], current, a[i], b[i], h, c2, c1, c0, dtf)
        else:
            for i in range(v.size):
                jump = row[i]
                vi = min(max(v[i] + jump, _F_FLOOR), _F_PEAK)
                row[i] = _F0
                current = _less_adaptation(noise_cur[i], adapt_a, adapt_g, i)
                current = _with_stim(current, stim_cur, i)
                current = _with_slow(current, slow, slow_gain, slow_decay, jump, i)
                v[i], u[i] = _izh_two(vi, u[i], current, a[i], b[i], h, c2, c1, c0, dtf)
        return
    # more sub-steps (dt > 1 ms): loop over sub-steps outside, neurons inside, so that
    # each pass still vectorises; h·(noise + stimulation − u) + c0 is held in `scratch`
    if redraw:
        fill_noise(noise_cur, noise_state, noise_mean, noise_sd)
    for i in range(v.size):
        jump = row[i]
        v[i] = max(v[i] + jump, _F_FLOOR)
        row[i] = _F0
        current = _with_stim(_less_adaptation(noise_cur[i], adapt_a, adapt_g, i), stim_cur, i)
        current = _with_slow(current, slow, slow_gain, slow_decay, jump, i)
        scratch[i] = h * (current - u[i]) + c0
    for _ in range(n_sub):
        for i in range(v.size):
            vi = min(v[i], _F_PEAK)
            v[i] = (c2 * vi + c1) * vi + scratch[i]
    for i in range(v.size):
        u[i] += dtf * a[i] * (b[i] * v[i] - u[i])


def ring_targets(delay_steps, post, n_neurons):
    """Each synapse's offset in the flattened delay ring: delay·n_neurons + post.

    int32 when the ring has fewer than 2^31 cells (halves the memory read per delivery),
    else int64. The slot of step k + delay is then (k mod n_slots)·n + offset, wrapped once.
    The kernel expects the offsets of each presynaptic neuron in ascending order (see
    `Network`, which sorts every CSR row by it): a row then splits into one run that does not
    wrap and one that does.

    Parameters
    ----------
    delay_steps : int array
        Each synapse's delay in steps (`connectivity.delay_steps`).
    post : int array
        Each synapse's postsynaptic neuron.
    n_neurons : int
        Neurons in the network (the ring's row length).

    Returns
    -------
    int32 or int64 array
        delay·n_neurons + post of each synapse.
    """
    n_slots = int(delay_steps.max()) + 1 if delay_steps.size else 2
    dtype = np.int32 if n_slots * n_neurons < 2**31 else np.int64
    return (delay_steps.astype(np.int64) * n_neurons + post).astype(dtype)


@njit(cache=True, nogil=True)
def _row_order(indptr, key, order):
    """Fill `order` with the permutation sorting each CSR row by key; True if not identity."""
    moved = False
    for i in range(indptr.size - 1):
        lo = indptr[i]
        hi = indptr[i + 1]
        sub = np.argsort(key[lo:hi], kind="mergesort")
        for t in range(hi - lo):
            order[lo + t] = lo + sub[t]
            moved |= sub[t] != t
    return moved


def row_order(indptr, key):
    """The permutation that sorts every CSR row by a key.

    Parameters
    ----------
    indptr : int64[n + 1]
        Row pointers.
    key : array
        One key per entry.

    Returns
    -------
    int64 array or None
        A stable within-row sort, or None when every row is already in order.
    """
    order = np.empty(key.size, dtype=np.int64)
    return order if _row_order(indptr, key, order) else None


@njit(cache=True, nogil=True)
def _deliver(ring_flat, base, target, weight, lo, hi, scale):
    """Add weight·scale of synapses lo:hi to the ring cells base + target (wrapped once).

    The targets of a row are ascending, so the synapses whose cell wraps past the ring's end
    are a tail found by bisection; the two runs then need no compare per synapse. Unsigned
    indices let the loops skip numba's negative-index fix-up.
    """
    ring_size = ring_flat.size
    lim = ring_size - base  # target >= lim wraps
    a = np.uint64(lo)
    b = np.uint64(hi)
    while a < b:
        m = (a + b) >> np.uint64(1)
        if target[m] < lim:
            a = m + np.uint64(1)
        else:
            b = m
    ub = np.uint64(base)
    for syn in range(np.uint64(lo), a):
        ring_flat[ub + np.uint64(target[syn])] += weight[syn] * scale
    ub = np.uint64(ring_size - base)  # cell = target - (ring_size - base) >= 0 in the tail
    for syn in range(a, np.uint64(hi)):
        ring_flat[np.uint64(target[syn]) - ub] += weight[syn] * scale


@njit(cache=True, nogil=True)
def _prefetch_row(indptr, target, weight, i):
    """Prefetch the synapse row of neuron i (targets and weights), one hint per cache line."""
    lo = np.uint64(indptr[i])
    hi = np.uint64(indptr[i + 1])
    if hi == lo:
        return
    for syn in range(lo, hi, np.uint64(16)):
        _prefetch(target, syn)
    for syn in range(lo, hi, np.uint64(8)):
        _prefetch(weight, syn)
    _prefetch(target, hi - np.uint64(1))  # the last line, which the strides may skip
    _prefetch(weight, hi - np.uint64(1))


@njit(cache=True, nogil=True, fastmath=_FAST)
def _izhikevich_spikes(v, u, c_reset, d_jump, k, out_neuron, out_step, n_out):
    """Record (in index order) and reset the neurons at the 30 mV peak; returns n_out.

    Eight neurons at a time are first tested with a branch-free max, so that the usual
    case (no spike among them) costs one branch per eight neurons instead of one per neuron.
    The record-and-reset body is written out twice on purpose: as a helper function, even
    inlined, it keeps numba from compiling this loop tightly, and the scan runs every step.
    """
    n8 = v.size - v.size % 8
    for lo in range(0, n8, 8):
        top = max(
            max(max(v[lo], v[lo + 1]), max(v[lo + 2], v[lo + 3])),
            max(max(v[lo + 4], v[lo + 5]), max(v[lo + 6], v[lo + 7])),
        )
        if top >= _F_PEAK:
            for i in range(lo, lo + 8):
                if v[i] >= _F_PEAK:
                    out_neuron[n_out] = i
                    out_step[n_out] = k
                    n_out += 1
                    v[i] = c_reset[i]
                    u[i] += d_jump[i]
    for i in range(n8, v.size):  # the last n mod 8 neurons (the same test, one by one)
        if v[i] >= _F_PEAK:
            out_neuron[n_out] = i
            out_step[n_out] = k
            n_out += 1
            v[i] = c_reset[i]
            u[i] += d_jump[i]
    return n_out


def _adaptation_factor(adapt_a, adapt_g, k, period):
    """g[k mod P] for step k, renormalising a (a ← a·g[P]) when k is a multiple of P."""
    j = k % period
    if adapt_a is not None and j == 0:
        for i in range(adapt_a.size):
            adapt_a[i] *= adapt_g[period]
    return adapt_g[j]


@overload(_adaptation_factor, inline="always")
def _adaptation_factor_impl(adapt_a, adapt_g, k, period):
    if isinstance(adapt_a, types.NoneType):
        return lambda adapt_a, adapt_g, k, period: adapt_g[0]

    def impl(adapt_a, adapt_g, k, period):
        j = k % period
        if j == 0:
            for i in range(adapt_a.size):
                adapt_a[i] *= adapt_g[period]
        return adapt_g[j]

    return impl


def _adapt_spike(adapt_a, adapt_inc, g_k, i):
    """Raise neuron i's adaptation current by its increment (nothing when it is off)."""
    if adapt_a is not None:
        adapt_a[i] += adapt_inc[i] / g_k


@overload(_adapt_spike, inline="always")
def _adapt_spike_impl(adapt_a, adapt_inc, g_k, i):
    if isinstance(adapt_a, types.NoneType):
        return lambda adapt_a, adapt_inc, g_k, i: None

    def impl(adapt_a, adapt_inc, g_k, i):
        adapt_a[i] += adapt_inc[i] / g_k

    return impl


@njit(cache=True, nogil=True)
def advance(n_steps, step0, neurons, wiring, dep, noise, stim, stdp, adapt, slow, out, n_out):
    """Advance the network by up to `n_steps` steps from absolute step `step0`.

    The state and parameters come in plain tuples, one per part of the model (plain, not
    named: numba types a plain tuple argument in C, a named one in Python, which would add a
    few µs to every call of a closed-loop step).

    Parameters
    ----------
    n_steps, step0 : int
        Steps to advance, and the absolute step to start from.
    neurons : (model, dt, n_sub, v, aux, params)
        ``model`` 0 Izhikevich, 1 LIF, 2 HH (``neurons.MODEL_IDS``); ``dt`` (ms); ``n_sub``
        Izhikevich Euler sub-steps per step; ``v`` float32[n] (mV); ``aux`` float32[k, n], the
        model's other state (Izhikevich: u and scratch; LIF: refractory steps left; HH: m, h,
        n and the above-threshold flag); ``params`` float32[p, n] (``neurons.build_params``).
    wiring : (ring, indptr, post, weight, target)
        ``ring`` float32[n_slots, n], the mV due at each step (slot k mod n_slots); the
        synapses in CSR form by presynaptic neuron (``indptr`` int64[n + 1], ``post``,
        ``weight`` float64 mV, changed by STDP); ``target`` each synapse's offset in the
        flattened ring, delay·n + post (`ring_targets`), ascending within each row, so that a
        delivery costs one add (no modulo, no compare).
    dep : (u, tau_steps, x, last)
        Short-term depression: resources used per spike (0: off), recovery time constant in
        steps, resources left float64[n] and step of the last spike int64[n].
    noise : (mean, sd, steps, state, cur)
        Background current redrawn per neuron every ``steps`` steps: mean and s.d.
        float32[n], xoshiro128++ states uint32[4, n], this window's current float32[n].
    stim : (neuron, current, start, end, cur)
        Pulses in neuron space on absolute steps [start, end) with their model current;
        ``cur`` float32[n] is scratch for a step's summed stimulation.
    stdp : (on, a_plus, a_minus, decay_plus, decay_minus, w_max, x_pre, y_post, in_indptr,
            in_syn, syn_pre, is_exc)
        Pair-based STDP of excitatory synapses: amplitudes (mV), per-step trace decays, the
        weight ceiling (mV), the traces float64[n], each neuron's incoming synapses (CSR
        ``in_indptr``, ``in_syn``), each synapse's presynaptic neuron, excitatory flags.
    adapt : (a, increment, g)
        Spike-frequency adaptation (Izhikevich model only). Neuron i's adaptation current at
        step k is a[i]·g[k mod P] (P = g.size − 1, `adaptation_period`): ``a`` float32[n]
        holds the amplitudes, renormalised (a ← a·g[P]) at the start of every step that is a
        multiple of P, so that the decay costs no store per neuron and step and the result
        does not depend on chunking; ``g`` float32[P + 1] the decay factors
        (`adaptation_factors`). A spike of neuron i adds ``increment[i]`` (float32[n]) to its
        current. It is subtracted from the neuron's input. ``a`` and ``increment`` are None
        when adaptation is off (that variant is compiled without it).
    slow : (current, gain, decay)
        Slow synaptic current (Izhikevich model only): ``current`` float32[n] decays by
        ``decay`` (float32, exp(−dt/τ)) every step, grows by ``gain`` (float32, share/τ per
        ms) × the jump arriving in that step, and is added to the neuron's input; so a jump of
        J mV brings in about share·J mV more over τ. ``current`` None when off.
    out : (neuron, step)
        Room for the spikes found (int32 and int64 arrays of the same length), written from
        index ``n_out`` on; a step needs room for n spikes.
    n_out : int

    Returns
    -------
    steps_done, n_out : int
        Fewer steps than asked only when the spike output arrays could overflow; call again
        with the remaining steps after draining them.
    """
    model, dt, n_sub, v, aux, params = neurons
    ring, indptr, post, weight, target = wiring
    dep_u, dep_tau_steps, dep_x, dep_last = dep
    noise_mean, noise_sd, noise_steps, noise_state, noise_cur = noise
    p_neuron, p_current, p_start, p_end, stim_cur = stim
    stdp_on, a_plus, a_minus, decay_plus, decay_minus, w_max = stdp[:6]
    x_pre, y_post, in_indptr, in_syn, syn_pre, is_exc = stdp[6:]
    adapt_a, adapt_inc, adapt_g = adapt
    adapt_period = adapt_g.size - 1
    slow_cur, slow_gain, slow_decay = slow
    out_neuron, out_step = out
    n = v.size
    n_slots = ring.shape[0]
    ring_size = ring.size
    ring_flat = ring.reshape(ring_size)
    cap = out_neuron.size
    n_p = p_neuron.size
    for i in range(n):
        stim_cur[i] = 0.0
    for s in range(n_steps):
        if cap - n_out < n:
            return s, n_out
        k = step0 + s
        redraw = k % noise_steps == 0
        if redraw and model != 0:  # the Izhikevich update draws its noise itself
            fill_noise(noise_cur, noise_state, noise_mean, noise_sd)
        for j in range(n_p):
            stim_cur[p_neuron[j]] = 0.0
        n_on = 0
        for j in range(n_p):
            if p_start[j] <= k and k < p_end[j]:
                stim_cur[p_neuron[j]] += p_current[j]
                n_on += 1
        g_k = _adaptation_factor(adapt_a, adapt_g, k, adapt_period)
        slot = k % n_slots
        row = ring[slot]
        base = slot * n
        first = n_out
        if model == 0:
            if n_on > 0:
                _izhikevich_update(
                    v, aux[0], params[0], params[1], row, noise_cur, noise_state, noise_mean,
                    noise_sd, redraw, stim_cur, aux[1], dt, n_sub, adapt_a, g_k,
                    slow_cur, slow_gain, slow_decay,
                )  # fmt: skip
            else:  # no pulse on: the variant that does not read the (all-zero) stim_cur
                _izhikevich_update(
                    v, aux[0], params[0], params[1], row, noise_cur, noise_state, noise_mean,
                    noise_sd, redraw, None, aux[1], dt, n_sub, adapt_a, g_k,
                    slow_cur, slow_gain, slow_decay,
                )  # fmt: skip
            n_out = _izhikevich_spikes(
                v, aux[0], params[2], params[3], k, out_neuron, out_step, n_out
            )
        elif model == 1:
            for i in range(n):
                vi = v[i] + row[i]
                row[i] = 0.0
                if aux[0, i] > 0.0:
                    aux[0, i] -= 1.0
                    vi = params[2, i]
                else:
                    v_inf = params[1, i] + params[4, i] * (noise_cur[i] + stim_cur[i])
                    vi = v_inf + (vi - v_inf) * math.exp(-dt / params[0, i])
                    if vi >= params[3, i]:
                        out_neuron[n_out] = i
                        out_step[n_out] = k
                        n_out += 1
                        vi = params[2, i]
                        aux[0, i] = params[5, i]
                v[i] = vi
        else:
            for i in range(n):
                vi = v[i] + row[i]
                row[i] = 0.0
                current = noise_cur[i] + stim_cur[i]
                vi, m, h, nn = _hh_step(vi, aux[0, i], aux[1, i], aux[2, i], current, params, i, dt)
                aux[0, i] = m
                aux[1, i] = h
                aux[2, i] = nn
                if vi >= HH_SPIKE_THRESHOLD_MV and aux[3, i] == 0.0:
                    aux[3, i] = 1.0
                    out_neuron[n_out] = i
                    out_step[n_out] = k
                    n_out += 1
                elif vi < HH_SPIKE_THRESHOLD_MV:
                    aux[3, i] = 0.0
                v[i] = vi
        if stdp_on:
            for i in range(n):
                x_pre[i] *= decay_plus
                y_post[i] *= decay_minus
        for q in range(first, n_out):
            i = out_neuron[q]
            _adapt_spike(adapt_a, adapt_inc, g_k, i)
            scale = 1.0
            if dep_u > 0.0:
                x = 1.0 - (1.0 - dep_x[i]) * math.exp(-(k - dep_last[i]) / dep_tau_steps)
                scale = x
                dep_x[i] = x * (1.0 - dep_u)
                dep_last[i] = k
            if q + 1 < n_out:  # the next spike's row is a DRAM miss; start fetching it now
                _prefetch_row(indptr, target, weight, out_neuron[q + 1])
            _deliver(ring_flat, base, target, weight, indptr[i], indptr[i + 1], scale)
            if stdp_on:
                for t in range(in_indptr[i], in_indptr[i + 1]):
                    syn = in_syn[t]
                    pre = syn_pre[syn]
                    if is_exc[pre]:
                        w = weight[syn] + a_plus * x_pre[pre]
                        weight[syn] = w if w < w_max else w_max
                if is_exc[i]:
                    for syn in range(indptr[i], indptr[i + 1]):
                        w = weight[syn] - a_minus * y_post[post[syn]]
                        weight[syn] = w if w > 0.0 else 0.0
        if stdp_on:
            for q in range(first, n_out):
                i = out_neuron[q]
                x_pre[i] += 1.0
                y_post[i] += 1.0
    return n_steps, n_out
