"""Slow drift in time: the machine warming up."""

from __future__ import annotations

from types import MappingProxyType

import numpy as np

from .base import Effect


class ThermalDrift(Effect):
    name, title = "thermal_drift", "slow drift in time: radial growth and pivot-to-spindle drift"
    commonness, geometric = 3, True
    limits = MappingProxyType({"*_um_per_h": 60.0})  # the brief: up to 40 um/h in a Z warm-up

    def columns(self, ctx, s, nl):
        th = s.tau_s / 3600.0
        # the spindle drifts in the machine's frame (a Z warm-up stays along Z while a
        # rotary table turns the bar); on a machine without a rotary table the same as u
        u = ctx.u_bed[s.idx]
        cols = np.column_stack([th, th * th, u[:, 0] * th, u[:, 1] * th, u[:, 2] * th])
        return cols, ("radial_um_per_h", "radial_um_per_h2", "x_um_per_h", "y_um_per_h",
                      "z_um_per_h")

    def parameters(self, coef, labels, nl, ctx):
        out = {lab: float(c) for lab, c in zip(labels, coef)}
        # the radial rate at the end of the program (the quadratic bends it)
        out["radial_end_um_per_h"] = out["radial_um_per_h"] + 2 * out.pop("radial_um_per_h2") * (
            ctx.duration_s / 3600.0)
        return out
