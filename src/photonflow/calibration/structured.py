"""A matrix with per-sensor block structure, solved by Schur complement.

The curvature of a calibration with P dense entries (scalars) and F per-sensor fields
over N sensors is

    [ A     U   ]     A: (P, P) dense-dense; U: dense-sensor, N blocks (P, F)
    [ C     B   ]     C: N blocks (F, P) sensor-dense; B: N blocks (F, F), block-diagonal

because a sensor's likelihood terms depend on its own per-sensor values only. A Fisher
information is symmetric (U = C^T); the derivative of the independent-ray score is not
(``c_upper`` holds U^T blockwise). Solving
and inverting cost O(N F^3 + P^3 + N F P^2) instead of O((P + N F)^3): with P = 4
optical parameters and 11,146 efficiencies that is milliseconds.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np


@dataclasses.dataclass(frozen=True)
class StructuredMatrix:
    """Curvature blocks in float64 numpy.

    Attributes:
        a: (P, P) dense-dense block.
        c: (N, F, P) sensor-dense blocks.
        b: (N, F, F) per-sensor diagonal blocks.
        c_upper: (N, F, P) the dense-sensor blocks transposed, U_j^T; None for a
            symmetric matrix (U_j = C_j^T, b symmetric).
    """

    a: np.ndarray
    c: np.ndarray
    b: np.ndarray
    c_upper: np.ndarray | None = None

    @property
    def symmetric(self) -> bool:
        """True for a symmetric matrix (no separate dense-sensor blocks)."""
        return self.c_upper is None

    @property
    def finite(self) -> bool:
        """True when every block is finite (no NaN or inf)."""
        return all(np.all(np.isfinite(block)) for block in (self.a, self.c, self.b, self.c_upper)
                   if block is not None)

    @property
    def _upper(self) -> np.ndarray:
        return self.c if self.c_upper is None else self.c_upper

    def transpose(self) -> StructuredMatrix:
        """The transposed matrix (itself when symmetric)."""
        if self.symmetric:
            return self
        return StructuredMatrix(self.a.T, self.c_upper, np.swapaxes(self.b, 1, 2), self.c)

    def damped(self, damping: float) -> StructuredMatrix:
        """Levenberg-Marquardt: every diagonal element multiplied by (1 + damping)."""
        a = self.a + damping * np.diag(np.diag(self.a))
        eye = np.eye(self.b.shape[1])
        b = self.b + damping * self.b * eye
        return StructuredMatrix(a, self.c, b, self.c_upper)

    def positive(self) -> StructuredMatrix:
        """The blocks A and B_j with their eigenvalues replaced by their magnitudes: a
        Fisher information (positive semi-definite; returned unchanged) that rounding
        has made slightly indefinite still gives a descent step and a meaningful size.
        Symmetric matrices only."""
        if not self.symmetric:
            raise ValueError("positive(): the matrix is not symmetric")

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
        out_dense = self.a @ dense + np.einsum("nfp,nf->p", self._upper, sensor)
        out_sensor = np.einsum("nfp,p->nf", self.c, dense) + np.einsum(
            "nfg,ng->nf", self.b, sensor
        )
        return out_dense, out_sensor

    def _inverse_blocks(self) -> np.ndarray:
        """B_j^-1 per sensor (pseudo-inverse: a block without information inverts to 0
        in its flat direction, and ``covariance`` reports it as infinite)."""
        if not self.b.shape[1]:
            return self.b
        return np.linalg.pinv(self.b, hermitian=self.symmetric)

    def schur(self, b_inverse: np.ndarray | None = None) -> np.ndarray:
        """S = A - sum_j U_j B_j^-1 C_j, (P, P)."""
        b_inverse = self._inverse_blocks() if b_inverse is None else b_inverse
        return self.a - np.einsum("nfp,nfg,ngq->pq", self._upper, b_inverse, self.c)

    def solve(self, dense: np.ndarray, sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """x with M x = (dense (P,), sensor (N, F)); returned as ((P,), (N, F))."""
        b_inverse = self._inverse_blocks()
        s = self.schur(b_inverse)
        binv_sensor = np.einsum("nfg,ng->nf", b_inverse, sensor)
        rhs = dense - np.einsum("nfp,nf->p", self._upper, binv_sensor)
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
        # (B^-1 C S^-1 U B^-1)_jj per sensor, diagonal only
        binv_c = np.einsum("nfg,ngp->nfp", b_inverse, self.c)
        upper_binv = np.einsum("ngp,ngf->nfp", self._upper, b_inverse)
        extra = np.einsum("nfp,pq,nfq->nf", binv_c, s_inverse, upper_binv)
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
        full[:p, p:] = self._upper.reshape(n * f, p).T
        for j in range(n):
            block = slice(p + j * f, p + (j + 1) * f)
            full[block, block] = self.b[j]
        return full


@dataclasses.dataclass(frozen=True)
class SandwichCovariance:
    """The covariance D^-1 (V + R) D^-T of the root of an estimating equation with
    derivative D (``newton``), data covariance V of its score (``information``,
    symmetric) and the score's covariance R from a second source of noise given as
    independent zero-mean samples s_r, R = sum_r s_r s_r^T (``noise_dense`` (S, P),
    ``noise_sensor`` (S, N, F); none by default).

    The dense block is exact (P structured solves with D^T); the per-sensor variances
    come from the diagonal of D^-1 alone (their estimating equations are the
    likelihood's to the precision that matters: a sensor's own derivative comes from its
    direct light, which has no ray noise, and the noise terms of a single sensor are
    small next to its Poisson statistics)."""

    newton: StructuredMatrix
    information: StructuredMatrix
    noise_dense: np.ndarray | None = None
    noise_sensor: np.ndarray | None = None

    @functools.cached_property
    def dense_rows(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The first P rows of D^-1 (the dense entries' response to the score), each as
        (dense part (P,), per-sensor part (N, F)) = D^-T e_k, a structured solve with D^T;
        -(row . score) is the first-order change of entry k. Computed once per
        instance."""
        p = self.newton.a.shape[0]
        n, f = self.newton.b.shape[:2]
        transposed = self.newton.transpose()
        return [transposed.solve(np.eye(p)[k], np.zeros((n, f))) for k in range(p)]

    @functools.cached_property
    def _dense_parts(self) -> tuple[np.ndarray, np.ndarray]:
        """(X V X^T, X R X^T), both (P, P), for X the rows of ``dense_rows``; computed
        once per instance, since the fit asks for the covariance, the noise share and
        the errors at the root."""
        rows = self.dense_rows
        images = [self.information.multiply(*row) for row in rows]
        data = np.array([
            [float(xd @ vd + np.sum(xs * vs)) for vd, vs in images] for xd, xs in rows
        ])
        if self.noise_dense is None:
            return data, np.zeros_like(data)
        projected = np.array([
            self.noise_dense @ xd + np.einsum("snf,nf->s", self.noise_sensor, xs)
            for xd, xs in rows
        ])  # (P, S)
        return data, projected @ projected.T

    def covariance(self) -> tuple[np.ndarray, np.ndarray]:
        """(dense covariance (P, P), per-sensor variances (N, F)), as
        ``StructuredMatrix.covariance``; inf where D is singular."""
        newton_dense, sensor = self.newton.covariance()
        if not newton_dense.size or not np.all(np.isfinite(newton_dense)):
            return newton_dense, sensor
        dense = sum(self._dense_parts)
        return 0.5 * (dense + dense.T), sensor

    def noise_share(self) -> np.ndarray:
        """(P,) the fraction of each dense entry's variance that comes from R."""
        if not self.newton.a.size:
            return np.zeros(0)
        data, noise = (np.diag(part) for part in self._dense_parts)
        return noise / (data + noise)


def _inverse_or_inf(matrix: np.ndarray) -> np.ndarray:
    """The inverse of a square matrix; where it is singular, the pseudo-inverse with inf
    on the diagonal of every entry that takes part in a flat direction (a right singular
    vector with a vanishing singular value)."""
    if not matrix.size:
        return matrix
    try:
        inverse = np.linalg.inv(matrix)
        if np.all(np.isfinite(inverse)):
            return inverse
    except np.linalg.LinAlgError:
        pass
    _, values, vectors_h = np.linalg.svd(matrix)
    flat = values <= 1e-12 * max(float(np.max(values)), 1e-300)
    inverse = np.linalg.pinv(matrix)
    involved = np.any(np.abs(vectors_h[flat, :]) > 1e-6, axis=0)
    inverse[involved, involved] = np.inf
    return inverse
