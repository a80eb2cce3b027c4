"""Which written parameters the data determine, in the parameters' own terms (not a condition number).

A free parameter is *determined* when three standard uncertainties of it move the tracked point by less than
:data:`LEVEL` of the robot's size (RMS over the fitted poses of its Jacobian column times the shift); when
the fit leaves a model error it cannot hold, the worst shift that error can give the parameter through least
squares (``ε · sqrt(3N) · ‖row of J⁺‖``, ε the model error per axis over N rows) is added, because σ covers the
noise only. A group of parameters whose correlation matrix has an eigenvalue below :data:`REDUNDANT` is only
determined as a combination (a near redundancy, e.g. a coupled joint's offsets): its members are named together.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

LEVEL = 0.01  # of the robot's size: what 3 sigma (plus the model-error bound) of a parameter may move the arm by
REDUNDANT = 1e-6  # eigenvalue of the correlation matrix: the combination is 1000x better known than its members
LOADING = 0.3  # share of a redundant combination's eigenvector that names a member


@dataclass(frozen=True)
class Parameter:
    """One free parameter: ``std`` (rad or m), ``bias`` the model error's worst shift (same unit), ``reach`` what
    3 std + bias move the tracked point by, as a share of the robot's size."""

    name: str
    std: float
    bias: float
    reach: float

    @property
    def angle(self) -> bool:
        return self.name.startswith(("theta", "alpha", "base.r"))

    def text(self) -> str:
        unit, factor = ("deg", np.degrees(1.0)) if self.angle else ("mm", 1e3)
        out = f"{self.name} ± {self.std * factor:.3g} {unit}"
        if self.bias > 0:
            out += f" (model error could move it {self.bias * factor:.3g} {unit})"
        return out


@dataclass(frozen=True)
class Identifiability:
    """The free parameters (:class:`Parameter`), the worst one, the near-redundant groups (names), and the
    parameters ``held`` at conventional values because the data did not separate them from others."""

    parameters: tuple[Parameter, ...]
    redundant: tuple[tuple[str, ...], ...]
    held: tuple[str, ...] = ()

    @property
    def poor(self) -> list[Parameter]:
        """Parameters not determined (reach beyond :data:`LEVEL`), worst first."""
        return sorted((p for p in self.parameters if p.reach > LEVEL), key=lambda p: -p.reach)

    @property
    def worst(self) -> Parameter | None:
        return max(self.parameters, key=lambda p: p.reach, default=None)


def identifiability(names: list[str], covariance: Array, lever: Array, size: float, model_error: float = 0.0,
                    scale: float = 1.0, rows: int = 0, held: tuple[str, ...] = ()) -> Identifiability:
    """Identifiability of the free parameters ``names`` with ``covariance`` (rad and m); ``lever`` (m per rad or
    m per m): how far a unit change of each moves the tracked point (RMS over the fitted poses); ``size`` (m): the
    robot's size; ``model_error`` (m per axis): the part of the residual the model does not hold, ``scale`` (m per
    axis): the noise level the covariance was scaled to, ``rows``: the 3D rows fitted (for the model-error bound);
    ``held``: the parameters fixed because the data did not determine them."""
    std = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    bias = std * model_error * np.sqrt(3 * rows) / scale if model_error > 0 and scale > 0 else np.zeros(len(std))
    params = []
    for name, s, b, arm in zip(names, std, bias, lever, strict=True):
        params.append(Parameter(name, float(s), float(b), float((3 * s + b) * arm / size)))
    return Identifiability(tuple(params), _redundant(names, covariance, std), held)


def _redundant(names: list[str], covariance: Array, std: Array) -> tuple[tuple[str, ...], ...]:
    """Groups of parameters only determined together: eigenvectors of the correlation matrix with eigenvalues
    below :data:`REDUNDANT`, named by their members of loading above :data:`LOADING`."""
    if len(std) < 2 or not np.all(std > 0):
        return ()
    corr = covariance / np.outer(std, std)
    values, vectors = np.linalg.eigh((corr + corr.T) / 2)
    groups = []
    for value, vector in zip(values, vectors.T, strict=True):
        if value >= REDUNDANT:
            break
        members = tuple(names[k] for k in np.flatnonzero(np.abs(vector) >= LOADING))
        if len(members) >= 2:
            groups.append(members)
    return tuple(groups)
