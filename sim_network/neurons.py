"""Neuron models: the published Izhikevich types, and per-neuron parameter/state arrays.

The kernel reads one `params` array of shape (n_params, n_neurons) and one `aux` state array
of shape (4, n_neurons) whose meaning depends on the model (see `initial_state`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from sim_network.config import NetworkConfig

# (a, b, c, d) from Izhikevich 2003/2004 ("Simple model of spiking neurons", Fig. 2).
IZHIKEVICH_TYPES: dict[str, tuple[float, float, float, float]] = {
    "RS": (0.02, 0.2, -65.0, 8.0),  # regular spiking (adapting)
    "IB": (0.02, 0.2, -55.0, 4.0),  # intrinsically bursting
    "CH": (0.02, 0.2, -50.0, 2.0),  # chattering
    "FS": (0.1, 0.2, -65.0, 2.0),  # fast spiking (no adaptation)
    "LTS": (0.02, 0.25, -65.0, 2.0),  # low-threshold spiking
    "TC": (0.02, 0.25, -65.0, 0.05),  # thalamo-cortical
    "RZ": (0.1, 0.26, -65.0, 2.0),  # resonator
}

MODEL_IDS = {"izhikevich": 0, "lif": 1, "hh": 2}
HH_V_REST_MV = -65.0


def izhikevich_params(
    cell_type: np.ndarray,
    exc_name: str,
    inh_name: str,
    heterogeneity_exc: float,
    heterogeneity_inh: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Per-neuron Izhikevich parameters with Izhikevich-2003-style spread.

    With r ~ U(0, 1) per neuron: excitatory c += 15·h_exc·r², d -= 6·h_exc·r² (RS drifts
    toward chattering); inhibitory a -= 0.08·h_inh·r (floored at 0.02), b += 0.05·h_inh·r
    (FS drifts toward LTS).

    Parameters
    ----------
    cell_type : uint8[n]
        0 excitatory, 1 inhibitory.
    exc_name, inh_name : str
        Keys of `IZHIKEVICH_TYPES` for each population (e.g. ``"RS"``, ``"FS"``).
    heterogeneity_exc, heterogeneity_inh : float
        Spread h of each population (0: all neurons alike).
    rng : numpy.random.Generator
        Draws r.

    Returns
    -------
    float64[4, n]
        Rows a, b, c (mV), d.
    """
    n = cell_type.size
    params = np.empty((4, n), dtype=np.float64)
    exc = cell_type == 0
    params[:, exc] = np.array(IZHIKEVICH_TYPES[exc_name])[:, None]
    params[:, ~exc] = np.array(IZHIKEVICH_TYPES[inh_name])[:, None]
    r = rng.random(n)
    params[2, exc] += 15.0 * heterogeneity_exc * r[exc] ** 2
    params[3, exc] = np.maximum(params[3, exc] - 6.0 * heterogeneity_exc * r[exc] ** 2, 0.05)
    params[0, ~exc] = np.maximum(params[0, ~exc] - 0.08 * heterogeneity_inh * r[~exc], 0.02)
    params[1, ~exc] += 0.05 * heterogeneity_inh * r[~exc]
    return params


def _hh_rates(v: float) -> tuple[float, float, float, float, float, float]:
    """HH opening/closing rates (1/ms) at v (mV); the same formulas as the kernel."""

    def vtrap(x: float, y: float) -> float:
        return y * (1.0 - x / y / 2.0) if abs(x / y) < 1e-6 else x / (math.exp(x / y) - 1.0)

    am = 0.1 * vtrap(-(v + 40.0), 10.0)
    bm = 4.0 * math.exp(-(v + 65.0) / 18.0)
    ah = 0.07 * math.exp(-(v + 65.0) / 20.0)
    bh = 1.0 / (1.0 + math.exp(-(v + 35.0) / 10.0))
    an = 0.01 * vtrap(-(v + 55.0), 10.0)
    bn = 0.125 * math.exp(-(v + 65.0) / 80.0)
    return am, bm, ah, bh, an, bn


def build_params(cfg: NetworkConfig, cell_type: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The per-neuron parameters of the configured model, as the kernel reads them.

    Parameters
    ----------
    cfg : NetworkConfig
        ``neurons`` (model and its parameters) and ``dt_ms``.
    cell_type : uint8[n]
        0 excitatory, 1 inhibitory.
    rng : numpy.random.Generator
        Draws the Izhikevich heterogeneity (unused by the other models).

    Returns
    -------
    float64[n_params, n]
        Izhikevich: a, b, c, d (`izhikevich_params`); LIF: tau_m_ms, v_rest_mv, v_reset_mv,
        v_threshold_mv, resistance, refractory steps; HH: g_na, g_k, g_leak, e_na_mv,
        e_k_mv, e_leak_mv, c_m, sub-steps per step.
    """
    n = cell_type.size
    neu = cfg.neurons
    if neu.model == "izhikevich":
        return izhikevich_params(
            cell_type,
            neu.excitatory_type,
            neu.inhibitory_type,
            neu.heterogeneity_exc,
            neu.heterogeneity_inh,
            rng,
        )
    if neu.model == "lif":
        p = neu.lif
        row = [p.tau_m_ms, p.v_rest_mv, p.v_reset_mv, p.v_threshold_mv, p.resistance]
        row.append(round(p.refractory_ms / cfg.dt_ms))
        return np.repeat(np.array(row, dtype=np.float64)[:, None], n, axis=1)
    p = neu.hh
    n_sub = max(1, math.ceil(cfg.dt_ms / p.substep_ms - 1e-9))
    row = [p.g_na, p.g_k, p.g_leak, p.e_na_mv, p.e_k_mv, p.e_leak_mv, p.c_m, n_sub]
    return np.repeat(np.array(row, dtype=np.float64)[:, None], n, axis=1)


def initial_state(cfg: NetworkConfig, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The state every neuron starts from (at rest).

    Parameters
    ----------
    cfg : NetworkConfig
        Which model.
    params : float64[n_params, n]
        From `build_params`.

    Returns
    -------
    v : float64[n]
        Membrane potential (mV).
    aux : float64[4, n]
        Izhikevich: u, scratch, the adaptation current (0); LIF: refractory steps left; HH:
        m, h, n, above-threshold flag.
    """
    n = params.shape[1]
    aux = np.zeros((4, n), dtype=np.float64)
    model = cfg.neurons.model
    if model == "izhikevich":
        v = np.full(n, -65.0)
        aux[0] = params[1] * v
    elif model == "lif":
        v = params[1].copy()
    else:
        v = np.full(n, HH_V_REST_MV)
        am, bm, ah, bh, an, bn = _hh_rates(HH_V_REST_MV)
        aux[0] = am / (am + bm)
        aux[1] = ah / (ah + bh)
        aux[2] = an / (an + bn)
    return v, aux


def izhikevich_substeps(dt_ms: float) -> int:
    """How many Euler sub-steps of v the Izhikevich update takes per step.

    Parameters
    ----------
    dt_ms : float
        The step.

    Returns
    -------
    int
        ceil(dt / 0.5 ms): 1 at dt <= 0.5 ms, 2 half-steps at 1 ms (Izhikevich 2003).
    """
    return max(1, math.ceil(dt_ms / 0.5 - 1e-9))
