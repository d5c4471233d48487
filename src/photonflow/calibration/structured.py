"""A symmetric matrix with per-sensor block structure, solved by Schur complement.

The curvature of a calibration with P dense entries (scalars) and F per-sensor fields
over N sensors is

    [ A     C^T ]     A: (P, P) dense-dense
    [ C     B   ]     C: N blocks (F, P) sensor-dense; B: N blocks (F, F), block-diagonal

because a sensor's likelihood terms depend on its own per-sensor values only. Solving
and inverting cost O(N F^3 + P^3 + N F P^2) instead of O((P + N F)^3): with P = 4
optical parameters and 11,146 efficiencies that is milliseconds.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class StructuredMatrix:
    """Curvature blocks in float64 numpy.

    Attributes:
        a: (P, P) dense-dense block.
        c: (N, F, P) sensor-dense blocks.
        b: (N, F, F) per-sensor diagonal blocks.
    """

    a: np.ndarray
    c: np.ndarray
    b: np.ndarray

    def damped(self, damping: float) -> StructuredMatrix:
        """Levenberg-Marquardt: every diagonal element multiplied by (1 + damping)."""
        a = self.a + damping * np.diag(np.diag(self.a))
        eye = np.eye(self.b.shape[1])
        b = self.b + damping * self.b * eye
        return StructuredMatrix(a, self.c, b)

    def positive(self) -> StructuredMatrix:
        """The blocks A and B_j with their eigenvalues replaced by their magnitudes: a
        Fisher information (positive semi-definite; returned unchanged) that rounding
        has made slightly indefinite still gives a descent step and a meaningful size."""

        def magnitude(blocks):
            values, vectors = np.linalg.eigh(blocks)
            if np.all(values >= 0):
                return blocks
            return np.einsum("...ik,...k,...jk->...ij", vectors, np.abs(values), vectors)

        a = magnitude(self.a) if self.a.size else self.a
        b = magnitude(self.b) if self.b.size else self.b
        return StructuredMatrix(a, self.c, b)

    def multiply(self, dense: np.ndarray, sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """M x for x = (dense (P,), sensor (N, F)); returned as ((P,), (N, F))."""
        out_dense = self.a @ dense + np.einsum("nfp,nf->p", self.c, sensor)
        out_sensor = np.einsum("nfp,p->nf", self.c, dense) + np.einsum(
            "nfg,ng->nf", self.b, sensor
        )
        return out_dense, out_sensor

    def _inverse_blocks(self) -> np.ndarray:
        """B_j^-1 per sensor (pseudo-inverse: a block without information inverts to 0
        in its flat direction, and ``covariance`` reports it as infinite)."""
        return np.linalg.pinv(self.b, hermitian=True) if self.b.shape[1] else self.b

    def schur(self, b_inverse: np.ndarray | None = None) -> np.ndarray:
        """S = A - sum_j C_j^T B_j^-1 C_j, (P, P)."""
        b_inverse = self._inverse_blocks() if b_inverse is None else b_inverse
        return self.a - np.einsum("nfp,nfg,ngq->pq", self.c, b_inverse, self.c)

    def solve(self, dense: np.ndarray, sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """x with M x = (dense (P,), sensor (N, F)); returned as ((P,), (N, F))."""
        b_inverse = self._inverse_blocks()
        s = self.schur(b_inverse)
        binv_sensor = np.einsum("nfg,ng->nf", b_inverse, sensor)
        rhs = dense - np.einsum("nfp,nf->p", self.c, binv_sensor)
        # least squares: a direction with no information (a probability saturating at 0
        # or 1 in logit coordinates) gets no step instead of a singular solve
        x_dense = np.linalg.lstsq(s, rhs, rcond=None)[0] if s.size else rhs
        x_sensor = np.einsum(
            "nfg,ng->nf", b_inverse, sensor - np.einsum("nfp,p->nf", self.c, x_dense)
        )
        return x_dense, x_sensor

    def covariance(self) -> tuple[np.ndarray, np.ndarray]:
        """The inverse's dense block (P, P) and the per-sensor diagonal variances (N, F).

        Where the matrix is singular (an unconstrained direction) the variances are inf.
        """
        b_inverse = self._inverse_blocks()
        s = self.schur(b_inverse)
        s_inverse = _inverse_or_inf(s)
        # (B^-1 C S^-1 C^T B^-1)_jj per sensor, diagonal only
        binv_c = np.einsum("nfg,ngp->nfp", b_inverse, self.c)
        extra = np.einsum("nfp,pq,nfq->nf", binv_c, s_inverse, binv_c)
        sensor = np.einsum("nff->nf", b_inverse) + extra
        flat_block = ~(np.einsum("nff->nf", self.b) > 0)
        return s_inverse, np.where(flat_block, np.inf, sensor)

    def dense_matrix(self) -> np.ndarray:
        """The full (P + N F) matrix (dense entries first, then sensor-major per-sensor
        entries); for tests and small problems only."""
        n, f, p = self.c.shape
        size = p + n * f
        full = np.zeros((size, size))
        full[:p, :p] = self.a
        c_flat = self.c.reshape(n * f, p)
        full[p:, :p] = c_flat
        full[:p, p:] = c_flat.T
        for j in range(n):
            block = slice(p + j * f, p + (j + 1) * f)
            full[block, block] = self.b[j]
        return full


@dataclasses.dataclass(frozen=True)
class SandwichCovariance:
    """The covariance M^-1 V M^-1 of the root of an estimating equation with symmetric
    derivative M and score covariance V (both ``StructuredMatrix``): the dense block
    exactly (P structured solves), the per-sensor variances from M alone (their
    estimating equations are the likelihood's to the precision that matters: a
    sensor's own derivative comes from its direct light, which has no ray noise)."""

    newton: StructuredMatrix
    information: StructuredMatrix

    def covariance(self) -> tuple[np.ndarray, np.ndarray]:
        """(dense covariance (P, P), per-sensor variances (N, F)), as
        ``StructuredMatrix.covariance``; inf where M is singular."""
        newton_dense, sensor = self.newton.covariance()
        p = self.newton.a.shape[0]
        if not p or not np.all(np.isfinite(newton_dense)):
            return newton_dense, sensor
        n, f = self.newton.b.shape[:2]
        columns = [self.newton.solve(np.eye(p)[k], np.zeros((n, f))) for k in range(p)]
        images = [self.information.multiply(*column) for column in columns]
        dense = np.array([
            [float(xd @ vd + np.sum(xs * vs)) for vd, vs in images] for xd, xs in columns
        ])
        return 0.5 * (dense + dense.T), sensor


def _inverse_or_inf(matrix: np.ndarray) -> np.ndarray:
    """The inverse of a symmetric matrix; where it is singular, the pseudo-inverse with
    inf on the diagonal of every entry that takes part in a flat direction."""
    if not matrix.size:
        return matrix
    try:
        inverse = np.linalg.inv(matrix)
        if np.all(np.isfinite(inverse)):
            return inverse
    except np.linalg.LinAlgError:
        pass
    values, vectors = np.linalg.eigh(matrix)
    flat = values <= 1e-12 * max(float(np.max(np.abs(values))), 1e-300)
    inverse = np.linalg.pinv(matrix, hermitian=True)
    involved = np.any(np.abs(vectors[:, flat]) > 1e-6, axis=1)
    inverse[involved, involved] = np.inf
    return inverse
