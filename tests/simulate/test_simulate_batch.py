"""simulate_amb_loops: many records of one bearing at once, each equal to its own
simulate_amb_loop.

Reference: the one-record simulator itself. Equality is bitwise (``array_equal``,
no tolerance): the batched loop does the same IEEE operations in the same order
per record (RK4 stages written alike, the observer/controller product the same
BLAS gemv per record), so any difference is a bug, not rounding.
"""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.exceptions import DataError, ModelError
from maglevid.physics.amb import AMBParameters
from maglevid.simulate.amb import simulate_amb_loop, simulate_amb_loops


class _NegatedNoise(np.random.Generator):
    """The bench's antithetic twin generator (benchmarks/bench_ml_crb.py): the
    (n, 3) sensor-noise draw negated."""

    def standard_normal(self, size=None, dtype=np.float64, out=None):
        x = super().standard_normal(size, dtype, out)
        return -x if isinstance(size, tuple) and len(size) == 2 and size[1] == 3 else x


def _assert_same(plant, makers, opts):
    """Each record of one batch equals simulate_amb_loop with a fresh rng made alike."""
    batch = simulate_amb_loops(plant, rngs=[make() for make in makers], **opts)
    for make, d in zip(makers, batch, strict=True):
        one = simulate_amb_loop(plant, rng=make(), **opts)
        for k in ("y", "u", "r", "u_f"):
            np.testing.assert_array_equal(getattr(d, k), getattr(one, k), err_msg=k)
        assert repr(d.metadata) == repr(one.metadata)
        assert repr(d.loop) == repr(one.loop)
    return batch


def _seed(s):
    return lambda: s


def _twin(seed):
    return lambda: _NegatedNoise(np.random.default_rng(seed).bit_generator)


@pytest.mark.parametrize(
    ("fault", "opts"),
    [
        # the hard case: a fault that moves the operating point, force disturbance,
        # sensor noise, the simulator's default 4 RK4 substeps
        ({"R1": 1.2}, {"force_std": 0.1}),
        # the bench's settings: one substep, no force, 3x noise
        ({}, {"substeps": 1, "force_std": 0.0, "noise_std": (3e-7, 3e-4, 3e-4)}),
    ],
)
def test_nonlinear_batch_is_each_record_alone_bit_for_bit(fault, opts):
    nom = AMBParameters.nominal()
    plant = nom.with_fault(**fault)
    opts = {"nominal": nom, "n_samples": 1500, "plant_model": "nonlinear", **opts}
    makers = [_seed(11), _seed(12), _twin(11), lambda: np.random.default_rng(5)]
    batch = _assert_same(plant, makers, opts)
    # the twin: same excitation, noise negated (what the bench's antithetic pair needs)
    np.testing.assert_array_equal(batch[2].r, batch[0].r)
    assert not np.array_equal(batch[2].y, batch[0].y)


def test_nonlinear_batch_with_sensor_gain_and_excitation_std():
    nom = AMBParameters.nominal()
    opts = {
        "nominal": nom,
        "n_samples": 800,
        "substeps": 2,
        "excitation_std": (0.5, 2.0),
        "sensor_gains": {"gx": 1.1},
    }
    batch = _assert_same(nom, [_seed(1), _seed(2)], opts)
    np.testing.assert_array_equal(batch[0].metadata["excitation"]["std"], [0.5, 2.0])


def test_linear_batch_is_each_record_alone():
    nom = AMBParameters.nominal()
    plant = nom.with_fault(R1=1.2)
    opts = {"nominal": nom, "n_samples": 2000, "plant_model": "linear"}
    _assert_same(plant, [_seed(3), _seed(4), _twin(3)], opts)


def test_batch_refuses_bad_options_with_one_clear_error():
    nom = AMBParameters.nominal()
    with pytest.raises(DataError, match="rngs"):
        simulate_amb_loops(nom, rngs=[], n_samples=100)
    with pytest.raises(DataError, match=r"\['rng'\]"):
        simulate_amb_loops(nom, rngs=[1], rng=1, n_samples=100)
    with pytest.raises(DataError, match="bogus"):
        simulate_amb_loops(nom, rngs=[1], bogus=3)
    with pytest.raises(DataError, match="n_samples"):
        simulate_amb_loops(nom, rngs=[1], n_samples=1)


def test_batch_names_the_record_that_hits_the_pole_face():
    """An excitation far beyond the loop's range throws the rotor into the pole
    face: the one-record loop raises ModelError, and so does the batch, naming
    the record."""
    nom = AMBParameters.nominal()
    opts = {"nominal": nom, "n_samples": 400, "excitation_std": 400.0, "force_std": 0.0}
    with pytest.raises(ModelError, match="pole face"):
        simulate_amb_loop(nom, rng=1, **opts)
    with pytest.raises(ModelError, match=r"record \d+: the rotor reached the pole face"):
        simulate_amb_loops(nom, rngs=[1, 2], **opts)
