"""Training the SIREN emission model (``siren.py``) on an emission table, with optax.

The training points are the table's knots as the spline model fits them
(``spline.footprint_densities``): every (energy above threshold, footprint width, x,
cos) node, the target h = sqrt(density per unit x per unit cos / yield). The loss is the
mean squared error in h over random batches (a Hellinger-like distance: the bright
Cherenkov peak and the faint tails both count), minimised by Adam with a cosine-decaying
learning rate. The batch of step k is drawn from a generator seeded by (seed, k), so a
run resumed from a checkpoint continues exactly as the uninterrupted one would; the
checkpoint (network, optimiser state, step, settings) is written atomically every
``checkpoint_every`` steps.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from ..errors import ConfigError
from ..generator.emission_tables import EmissionTable
from ..progress import with_progress
from .siren import Siren, energy_input, footprint_input
from .spline import FOOTPRINT_WIDTHS, footprint_densities


@dataclasses.dataclass(frozen=True)
class SirenSettings:
    """Network and training settings of a SIREN emission model.

    Attributes:
        width: units per hidden layer. depth: hidden layers. omega: the sine layers'
            frequency scale.
        steps: Adam steps. batch: points per step. learning_rate: the first step's;
            it decays (cosine) to ``learning_rate x final_share``.
        seed: seeds the initial weights and every batch.
        checkpoint_every: steps between checkpoints.
    """

    width: int = 128
    depth: int = 3
    omega: float = 30.0
    steps: int = 4000
    batch: int = 16384
    learning_rate: float = 1e-3
    final_share: float = 0.01
    seed: int = 0
    checkpoint_every: int = 250

    def __post_init__(self):
        for name in ("width", "depth", "steps", "batch", "checkpoint_every"):
            if int(getattr(self, name)) < 1:
                raise ConfigError(f"{name} = {getattr(self, name)!r}: must be at least 1")
        for name in ("omega", "learning_rate", "final_share"):
            if not float(getattr(self, name)) > 0:
                raise ConfigError(f"{name} = {getattr(self, name)!r}: must be positive")


def training_points(table: EmissionTable, threshold: float):
    """(inputs (P, 4) float32 in [-1, 1], targets (P,) float32 h, the table's (E, W, D, A)
    shape, its yields (E,)) of ``table`` above ``threshold`` (MeV) (module docstring)."""
    table, fraction, cos, averaged = footprint_densities(table, threshold)
    log_energy = np.log(np.concatenate([[threshold], np.asarray(table.energies, float)]))
    energy = np.asarray(energy_input(jnp.asarray(log_energy), jnp.asarray(table.energies)))
    footprint = np.asarray(footprint_input(jnp.asarray(FOOTPRINT_WIDTHS), jnp.float64))
    grids = np.meshgrid(energy, footprint, 2.0 * fraction - 1.0, cos, indexing="ij")
    inputs = np.stack(grids, axis=-1).reshape(-1, 4).astype(np.float32)
    target = np.sqrt(averaged / table.total_yield[:, None, None, None])
    return inputs, target.reshape(-1).astype(np.float32), averaged.shape, table.total_yield


def train_siren(table: EmissionTable, threshold: float, settings: SirenSettings | None = None,
                *, checkpoint: str | Path | None = None, progress: bool = False,
                check=None) -> tuple[Siren, dict]:
    """Train a ``Siren`` on ``table`` (``threshold``: the particle's Cherenkov threshold
    in the table's medium, MeV). ``checkpoint``: a file to resume from (if it exists)
    and to write every ``settings.checkpoint_every`` steps; ``check``: called between
    steps (raises to stop, e.g. on an interrupt). Returns (network, history: the step
    numbers and mean losses of each checkpoint interval)."""
    settings = SirenSettings() if settings is None else settings
    inputs, targets, _, _ = training_points(table, threshold)
    schedule = optax.cosine_decay_schedule(settings.learning_rate, settings.steps,
                                           settings.final_share)
    optimiser = optax.adam(schedule)
    network = Siren(settings.width, settings.depth, settings.omega,
                    jax.random.key(settings.seed))
    state = optimiser.init(network)
    step, history = 0, {"step": [], "loss": []}
    header = {"settings": dataclasses.asdict(settings), "particle": table.particle,
              "medium": table.medium}
    if checkpoint is not None and Path(checkpoint).exists():
        network, state, step, history = _resume(checkpoint, header, network, state)

    @eqx.filter_jit
    def update(network, state, x, y):
        loss, grads = eqx.filter_value_and_grad(
            lambda net: jnp.mean((net(x) - y) ** 2))(network)
        with jax.numpy_dtype_promotion("standard"):  # optax mixes int and float
            updates, state = optimiser.update(grads, state, network)
        return eqx.apply_updates(network, updates), state, loss

    losses = []
    for k in with_progress(range(step, settings.steps), "SIREN training",
                           total=settings.steps, completed=step, show=progress):
        rng = np.random.default_rng([settings.seed, k])
        index = rng.integers(0, inputs.shape[0], settings.batch)
        network, state, loss = update(network, state, inputs[index], targets[index])
        losses.append(float(loss))
        if (k + 1) % settings.checkpoint_every == 0 or k + 1 == settings.steps:
            history["step"].append(k + 1)
            history["loss"].append(float(np.mean(losses)))
            losses = []
            if checkpoint is not None:
                _save_checkpoint(checkpoint, header, network, state, k + 1, history)
        if check is not None:
            check()
    return network, history


def _save_checkpoint(path, header, network, state, step, history) -> None:
    """Write (header with ``step`` and ``history``, network and optimiser state) to
    ``path`` atomically."""
    path = Path(path)
    temporary = path.with_name(path.name + ".part")
    with open(temporary, "wb") as stream:
        stream.write((json.dumps({**header, "step": step, "history": history}) + "\n")
                     .encode())
        eqx.tree_serialise_leaves(stream, (network, state))
    temporary.replace(path)


def _resume(path, header, network, state):
    """(network, optimiser state, step, history) from the checkpoint at ``path``;
    ``ConfigError`` when it was written for other settings or another table."""
    with open(path, "rb") as stream:
        saved = json.loads(stream.readline())
        for name in ("particle", "medium"):
            if saved.get(name) != header[name]:
                raise ConfigError(f"--checkpoint = {str(path)!r}: written for {name} ="
                                  f" {saved.get(name)!r}, not {header[name]!r}")
        for name, value in header["settings"].items():
            if saved["settings"].get(name) != value:
                raise ConfigError(f"--checkpoint = {str(path)!r}: written for {name} ="
                                  f" {saved['settings'].get(name)!r}, not {value!r}")
        network, state = eqx.tree_deserialise_leaves(stream, (network, state))
    return network, state, int(saved["step"]), saved["history"]


def fit_report(network: Siren, table: EmissionTable, threshold: float) -> list[dict]:
    """Fit quality of ``network`` on ``table``'s knots, per energy: ``energy`` (MeV);
    ``profile_chi2``: the angular profile (photons per cos bin of the density itself,
    summed over the distance bins at their centres) against the table's, chi2 per bin
    with the table's errors over the bins holding 99 % of the light; ``normalisation``:
    the network's sum of h^2 over the table's bins minus 1 (the yield error before the
    model rescales it to the yield spline); ``rms_h``: rms error of h over all the
    knots, relative to the rms of h."""
    inputs, targets, shape, yields = training_points(table, threshold)
    merged = footprint_densities(table, threshold)[0]
    evaluate = jax.jit(lambda net, z: net(z))
    predicted = np.concatenate([np.asarray(evaluate(network, jnp.asarray(chunk)))
                                for chunk in np.array_split(inputs, -(-len(inputs) // 2**17))]
                               ).reshape(shape)
    targets = targets.reshape(shape)
    cos_widths = np.diff(merged.cos_edges)
    rows = []
    for k, energy in enumerate(merged.energies):
        cells = np.diff(merged.distance_edges[k]) / merged.distance_edges[k, -1]
        density = predicted[k, 0] ** 2  # (D, A) per unit x per unit cos, per photon
        profile = (cells @ density) * cos_widths * yields[k]
        reference = merged.photons[k].sum(axis=0)
        order = np.argsort(reference)[::-1]
        bright = order[: np.searchsorted(np.cumsum(reference[order]),
                                         0.99 * reference.sum()) + 1]
        error = np.maximum(merged.angular_error[k], 1e-12)
        rows.append({
            "energy": float(energy),
            "profile_chi2": float(np.mean(((profile - reference)[bright] / error[bright]) ** 2)),
            "normalisation": float(np.sum(cells @ density * cos_widths) - 1.0),
            "rms_h": float(np.sqrt(np.mean((predicted[k] - targets[k]) ** 2)
                                   / np.mean(targets[k] ** 2))),
        })
    return rows
