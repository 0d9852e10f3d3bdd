"""Geometric error model of the configured chain, with ISO 230-1/-7 names.

Every axis K carries six component errors, functions of its own position: the
translations EXK, EYK, EZK (um) and the rotations EAK, EBK, ECK (urad), e.g. EXX is the
positioning error of X, EYX its straightness in Y, ECX its yaw.  Each is expanded in a
basis: for linear axes constant, Legendre polynomials over the tested travel, or a
table (piecewise linear); for rotary axes a Fourier series in the angle.  Parameter
names: ``EXX`` (constant), ``EXX.P2`` (Legendre degree 2), ``EXX.T3`` (table node 3),
``EXC.c1`` / ``EXC.s1`` (first harmonic).

Squareness of the linear axes: ``EC0Y`` (Y against X, about Z), ``EB0Z`` (Z against X,
about Y), ``EA0Z`` (Z against Y, about X).  Location errors of rotary axes (ISO 230-7):
C: ``EX0C EY0C EA0C EB0C``; B: ``EX0B EZ0B EA0B EC0B``; A: ``EY0A EZ0A EB0A EC0A``.

Where they act: the component errors of axis K form a small rigid motion applied right
after K's nominal motion, in K's body frame (whose origin, with every axis at 0, is the
bed origin); location errors a constant small motion about K's axis point, applied
before it; squareness tilts a linear axis' direction.  Internally values are in mm and
rad; parameters are in um and urad.

The paper's symbols map as ``delta_{xy'} = EYX`` (translation of axis X along y) and
``epsilon_{xy'} = EBX`` (rotation of axis X about y): the first index is the axis, the
second the direction (Eq. 10 of the paper); see :data:`PAPER_SYMBOLS`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import MachineConfig

COMPONENTS = ("X", "Y", "Z", "A", "B", "C")  # translations along, rotations about
UM, URAD = 1e-3, 1e-6  # parameter unit -> internal unit

#: Squareness parameters: name -> (the tilted axis, rotation axis index 0/1/2).
SQUARENESS = {"EC0Y": ("Y", 2), "EB0Z": ("Z", 1), "EA0Z": ("Z", 0)}
#: Location errors per rotary axis: (translation directions, rotation directions).
LOCATION = {"C": ("XY", "AB"), "B": ("XZ", "AC"), "A": ("YZ", "BC")}

#: The paper's symbols (Table 1, Eq. 10) -> ISO names.
PAPER_SYMBOLS = {
    f"{kind}_{axis.lower()}{comp.lower()}'": f"E{iso}{axis}"
    for axis in "XYZBC"
    for kind, comps in (("delta", "XYZ"), ("epsilon", "XYZ"))
    for comp, iso in zip(comps, ("XYZ" if kind == "delta" else "ABC"))
}


@dataclass(frozen=True, slots=True)
class Parameter:
    """One model parameter.  ``kind``: ``component``, ``squareness`` or ``location``;
    ``component``: index 0-5 (X Y Z A B C); ``basis``: ``const``, ``P<n>``, ``T<n>``,
    ``c<n>``, ``s<n>``; ``unit``: ``um`` or ``urad``."""

    name: str
    kind: str
    axis: str
    component: int
    basis: str
    unit: str

    @property
    def scale(self) -> float:
        """Internal units per parameter unit."""
        return UM if self.unit == "um" else URAD


@dataclass(frozen=True, slots=True)
class ModelOptions:
    """``linear_basis``: ``legendre`` or ``table``; ``linear_order``: Legendre degree
    (0 = constants) or table nodes - 1; ``rotary_order``: Fourier harmonics;
    ``squareness``, ``location``: include those parameters."""

    linear_basis: str = "legendre"
    linear_order: int = 0
    rotary_order: int = 0
    squareness: bool = True
    location: bool = True


@dataclass(frozen=True, slots=True)
class ErrorModel:
    """The parameters of a chain, and the travel the linear bases are scaled to
    (``travel`` axis -> (lo, hi) in mm, normally the tested travel)."""

    axes: tuple[str, ...]
    rotary: tuple[str, ...]
    parameters: tuple[Parameter, ...]
    travel: tuple[tuple[str, float, float], ...]
    options: ModelOptions

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    def index(self, name: str) -> int:
        for i, p in enumerate(self.parameters):
            if p.name == name:
                return i
        raise KeyError(name)

    def basis_values(self, param: Parameter, q: np.ndarray) -> np.ndarray:
        """The basis function of ``param`` at axis values ``q (n,)`` (mm or rad)."""
        if param.basis == "const":
            return np.ones_like(q)
        kind, k = param.basis[0], int(param.basis[1:])
        if kind in "cs":
            return np.cos(k * q) if kind == "c" else np.sin(k * q)
        lo, hi = next((a, b) for n, a, b in self.travel if n == param.axis)
        x = np.clip((2.0 * q - (lo + hi)) / max(hi - lo, 1e-9), -1.0, 1.0)
        if kind == "P":
            return np.polynomial.legendre.legval(x, [0.0] * k + [1.0])
        nodes = self.options.linear_order
        pos = (x + 1.0) / 2.0 * nodes
        return np.clip(1.0 - np.abs(pos - k), 0.0, 1.0)  # hat function of table node k


def build_model(machine: MachineConfig, travel: dict[str, tuple[float, float]],
                options: ModelOptions = ModelOptions()) -> ErrorModel:
    """All parameters for ``machine`` with ``options``; ``travel`` holds the tested
    range of every linear axis (mm)."""
    names = machine.workpiece_chain + machine.tool_chain
    rotary = tuple(a.name for a in machine.rotary_axes)
    params: list[Parameter] = []
    for axis in names:
        is_rot = axis in rotary
        for c, comp in enumerate(COMPONENTS):
            unit = "um" if c < 3 else "urad"
            base = f"E{comp}{axis}"
            if is_rot:
                bases = ["const"] + [f"{t}{k}" for k in range(1, options.rotary_order + 1)
                                     for t in "cs"]
            elif options.linear_basis == "table":
                bases = [f"T{k}" for k in range(options.linear_order + 1)]
            else:
                bases = ["const"] + [f"P{k}" for k in range(1, options.linear_order + 1)]
            for b in bases:
                name = base if b == "const" else f"{base}.{b}"
                params.append(Parameter(name, "component", axis, c, b, unit))
    if options.squareness:
        for name, (axis, rot) in SQUARENESS.items():
            if axis in names and "X" in names:
                params.append(Parameter(name, "squareness", axis, 3 + rot, "const", "urad"))
    if options.location:
        for axis in rotary:
            trans, rots = LOCATION[axis]
            for t in trans:
                params.append(Parameter(f"E{t}0{axis}", "location", axis, "XYZ".index(t),
                                        "const", "um"))
            for r in rots:
                params.append(Parameter(f"E{r}0{axis}", "location", axis, 3 + "ABC".index(r),
                                        "const", "urad"))
    trav = tuple((a, float(travel[a][0]), float(travel[a][1])) for a in names if a in travel)
    return ErrorModel(names, rotary, tuple(params), trav, options)


def prior_scale(param: Parameter) -> float:
    """A typical magnitude (um or urad) used to scale columns and as the Tikhonov prior:
    10 um / 20 urad for component and location errors, 20 urad for squareness; higher
    basis terms half of that."""
    base = 20.0 if param.unit == "urad" else 10.0
    if param.basis not in ("const",) and not param.basis.startswith("T"):
        base *= 0.5
    return base


def values_vector(model: ErrorModel, values: dict[str, float]) -> np.ndarray:
    """Parameter values (um, urad) in model order; names not in the model raise."""
    theta = np.zeros(len(model.parameters))
    for name, v in values.items():
        theta[model.index(name)] = v
    return theta


def component_errors(model: ErrorModel, theta: np.ndarray, q: np.ndarray,
                     axis_index: dict[str, int]) -> dict[str, np.ndarray]:
    """Per axis the component errors ``(n, 6)`` (mm, rad) at axis values ``q``."""
    n = len(q)
    out = {a: np.zeros((n, 6)) for a in model.axes}
    for p, v in zip(model.parameters, theta):
        if v == 0.0 or p.kind != "component":
            continue
        out[p.axis][:, p.component] += v * p.scale * model.basis_values(p, q[:, axis_index[p.axis]])
    return out
