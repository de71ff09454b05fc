import numpy as np
import pytest

from sparsebtf.data.directions import by_name, from_angles, from_vectors, tiny, ubo2003, ubo2014
from sparsebtf.errors import BTFInputError


def test_ubo2014_matches_release_table(official):
    table = np.fromfile(official / "bonn_angles.bin", dtype="<f8").reshape(3, 151)
    d = ubo2014()
    assert len(d) == 151
    # The release stores float32-computed angles: equal to float32 rounding.
    assert np.abs(d.phi - table[0]).max() < 2e-6
    assert np.abs(d.elevation - table[1]).max() < 2e-6
    assert np.array_equal(table[2], np.arange(1, 152))
    xyz = np.fromfile(official / "xyz_loc.bin", dtype="<f8").reshape(4, 151)[:3].T
    assert np.abs(d.xyz - xyz).max() < 2e-6


def test_ubo2014_rings_without_release():
    d = ubo2014()
    polar = np.degrees(d.theta)
    assert polar[0] == 0
    assert np.allclose(polar[1:7], 11) and np.allclose(polar[127:], 75)
    assert np.allclose(np.linalg.norm(d.xyz, axis=1), 1)
    assert np.all(d.phi >= -np.pi) and np.all(d.phi < np.pi)


def test_other_sets():
    assert len(ubo2003()) == 81
    assert [len(tiny(n)) for n in (7, 13, 19)] == [7, 13, 19]
    assert by_name("UBO2014").name == "ubo2014"
    assert len(by_name("tiny13")) == 13


def test_nearest_by_chord_distance():
    d = ubo2014()
    idx, dist = d.nearest(d.xyz, k=3)
    assert np.array_equal(idx[:, 0], np.arange(151))
    assert np.allclose(dist[:, 0], 0, atol=1e-7)
    assert np.all(np.diff(dist, axis=1) >= 0)
    # brute force check on random queries
    rng = np.random.default_rng(0)
    q = rng.standard_normal((50, 3))
    q[:, 2] = np.abs(q[:, 2])
    idx, dist = d.nearest(q, k=2)
    qn = q / np.linalg.norm(q, axis=1, keepdims=True)
    full = np.linalg.norm(qn[:, None, :] - d.xyz[None], axis=2)
    assert np.allclose(dist, np.sort(full, axis=1)[:, :2])


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: by_name("ubo1999"), "unknown direction set"),
        (lambda: tiny(5), "tiny direction sets"),
        (lambda: from_angles([0.1, 2.0], [0, 0]), "outside"),
        (lambda: from_angles([0.1], [0, 1]), "differ in length"),
        (lambda: from_vectors(np.zeros((2, 3))), "zero or not finite"),
        (lambda: from_vectors(np.ones((2, 2))), r"shape \(n, 3\)"),
        (lambda: from_vectors(np.array([[0, 0, -1.0]])), "below the surface"),
        (lambda: ubo2014().nearest(np.ones((2, 2))), "last axis of 3"),
        (lambda: ubo2014().nearest(np.ones(3), k=0), "k must be"),
    ],
)
def test_bad_directions(call, match):
    with pytest.raises(BTFInputError, match=match):
        call()
