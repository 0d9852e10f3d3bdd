"""Play: lost motion along a reversing axis, and a step across it."""

from __future__ import annotations

from types import MappingProxyType

import numpy as np

from ...reading.context import Context
from .base import NEGLIGIBLE, Effect, linear_axes, projection_gain


#: rest at the start (s) before an axis' first move long enough to read the play's
#: unknown state there (shorter, its few samples are left to the residual)
START_REST_S = 0.2


#: least bar sensitivity to an axis (um per um) at the start for its play's state there
#: to be read (below it, a column of a few hundredths fits noise with an absurd size)
START_GAIN = 0.1


def _start_rest_s(ctx: Context, j: int) -> float:
    """How long (s) axis j stands at the start before it has moved 0.5 um."""
    moved = np.flatnonzero(np.abs(ctx.q[:, j] - ctx.q[0, j]) > 0.5e-3)
    return float(ctx.t_s[moved[0]] - ctx.t_s[0]) if moved.size else 0.0


class Backlash(Effect):
    name, title = "backlash", "lost motion: a step at each reversal of an axis (play operator)"
    headline = 1
    commonness = 4
    reverse, feed_power = -1, 0.0
    limits = MappingProxyType({"play_*": 80.0, "slack_at_start_*": 80.0})
    grid_um = (0.5, 1.0, 2.0, 3.0, 4.5, 6.5, 9.0, 13.0, 18.0, 25.0, 35.0, 50.0)

    def search(self, ctx, s, r):
        out = {}
        for j in linear_axes(ctx):
            if not len(ctx.reversal_times[j]):
                continue
            g = [projection_gain(self._col(ctx, s, j, b)[:, None], r) for b in self.grid_um]
            if max(g) <= NEGLIGIBLE * float(r @ r):
                # an axis the bar barely sees here (Z on a level bar): its play column,
                # fitted on noise, takes an absurd size and wrecks the held-out stretches
                continue
            b = float(self.grid_um[int(np.argmax(g))])
            for _ in range(3):  # the column's shape depends on the play: iterate to it
                c = self._col(ctx, s, j, b)
                den = float(c @ c)
                fitted = abs(float(c @ r) / den) if den > 0 else b
                if not 0.2 <= fitted <= 100.0 or abs(fitted - b) < 0.02 * b:
                    break
                b = fitted
            out[f"width_{ctx.axis_names[j]}_um"] = b
            if (_start_rest_s(ctx, j) >= START_REST_S
                    and abs(float(ctx.gain[0, j])) >= START_GAIN):
                out[f"slack_{ctx.axis_names[j]}_um"] = self._slack(ctx, s, j, b, r)
        return out or None

    def _slack(self, ctx, s, j, width_um, r) -> float:
        """How far (um, 0 to the play) the command moves axis j at the start before the
        axis follows, iterated like the play: the start column's shape depends on it."""
        sig = width_um / 2.0  # the middle of the play, with nothing known
        for _ in range(3):
            C = np.column_stack([self._col(ctx, s, j, width_um),
                                 self._start_col(ctx, s, j, sig)])
            coef = np.linalg.lstsq(C, r, rcond=None)[0]
            fitted = float(min(max(coef[1], 0.05), width_um))
            if abs(fitted - sig) < 0.02 * sig:
                break
            sig = fitted
        return sig

    def _start_col(self, ctx, s, j, slack_um):
        """Bar reading (um per um of slack) of where the play stood at the start, beyond
        the taken-up state :meth:`_col` assumes there: the axis stands until the command
        has moved ``slack_um`` from where it began, then follows."""
        i = s.idx
        sig = max(slack_um, 0.05) * 1e-3
        far = np.flatnonzero(np.abs(ctx.q[:, j] - ctx.q[0, j]) >= sig)
        end = int(far[0]) if far.size else ctx.n
        moved = np.abs(ctx.q[i, j] - ctx.q[0, j])
        ramp = np.where(i < end, 1.0 - moved / sig, 0.0)
        return ctx.gain[i, j] * ctx.direction[0, j] * ramp

    def _col(self, ctx, s, j, width_um):
        """Bar reading (um per um of play) of a play operator of ``width_um`` on axis j:
        after a reversal the axis stands until the command has moved the play."""
        i = s.idx
        x = ctx.q[i, j]
        d = ctx.direction[i, j]
        x_rev = ctx.position_at_reversal(i, j)
        b = width_um * 1e-3
        moved = np.abs(x - x_rev)
        dev = np.where(np.isfinite(x_rev) & (moved < b), x_rev - x + d * b / 2.0, -d * b / 2.0)
        return ctx.gain[i, j] * dev / b

    def columns(self, ctx, s, nl):
        axes = [j for j in linear_axes(ctx) if f"width_{ctx.axis_names[j]}_um" in nl]
        cols = [self._col(ctx, s, j, nl[f"width_{ctx.axis_names[j]}_um"]) for j in axes]
        labels = [f"play_{ctx.axis_names[j]}_um" for j in axes]
        # Where the play stood when the recording began is not known: the last move
        # before the program left it anywhere across its width.  :meth:`_col` takes it
        # up in the first direction; the slack left at the start (how far the command
        # moves before the axis follows) is a column of its own, read from the rest
        # before the first move.  (Read as taken up, a play that stood in its middle
        # leaves half its width unexplained over that rest, and a reversal spike is
        # invented for it; hard case: blind-bad-SDIT5_C-s2-4.)
        for j in axes:
            key = f"slack_{ctx.axis_names[j]}_um"
            if key in nl:
                cols.append(self._start_col(ctx, s, j, nl[key]))
                labels.append(f"slack_at_start_{ctx.axis_names[j]}_um")
        return np.column_stack(cols), tuple(labels)

    def parameters(self, coef, labels, nl, ctx):
        return {lab: float(c) for lab, c in zip(labels, coef)}

    def from_fit(self, nl, coef, labels):
        # the plays and slacks the columns are shaped with, as fitted with the others in
        # (searched alone, a slack comes out a fraction of what the fit makes it, and
        # the start column's shape then holds the timing milliseconds late; hard case:
        # blind-bad-SDIT5_C-s1-38); a play the fit puts outside the search's range
        # keeps its own
        fitted = {lab: float(c) for lab, c in zip(labels, coef)}
        out = dict(nl)
        def axis(key, prefix):  # width_<axis>_um -> <axis>
            return key[len(prefix):-len("_um")]

        for key in nl:
            if key.startswith("width_"):
                c = abs(fitted.get(f"play_{axis(key, 'width_')}_um", 0.0))
                if 0.2 <= c <= 100.0:
                    out[key] = round(c, 4)
        for key in nl:
            if key.startswith("slack_"):
                a = axis(key, "slack_")
                top = out.get(f"width_{a}_um", nl[key])
                c = fitted.get(f"slack_at_start_{a}_um", nl[key])
                out[key] = round(float(min(max(c, 0.05), top)), 4)
        return out


class LateralPlay(Effect):
    name, title = "lateral_play", "a step across the reversing axis (guide play)"
    commonness = 11
    reverse, feed_power = -1, 0.0
    limits = MappingProxyType({"play_*": 15.0})

    def columns(self, ctx, s, nl):
        cols, labels = [], []
        g, d = ctx.gain[s.idx], ctx.direction[s.idx]  # (every axis' at once)
        for j in linear_axes(ctx):
            if not len(ctx.reversal_times[j]):
                continue
            for k in linear_axes(ctx):
                if k != j:
                    cols.append(g[:, k] * d[:, j] / 2.0)
                    labels.append(f"play_{ctx.axis_names[k]}_on_{ctx.axis_names[j]}_reversal_um")
        return (np.column_stack(cols) if cols else np.zeros((len(s.idx), 0))), tuple(labels)
