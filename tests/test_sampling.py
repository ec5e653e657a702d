"""Host sampling (#24 start-up): the vectorised samplers give the same points, in the same order, as the plain
ones they replaced (written out here as references), and importing the simulator does not load trimesh."""

import subprocess
import sys

import numpy as np
import pytest

from warpsph import sampling


def fill_block_reference(start, end, spacing):
    start, end = np.asarray(start, np.float64), np.asarray(end, np.float64)
    counts = np.floor((end - start) / spacing + 1e-6).astype(int)
    if np.any(counts < 1):
        return np.zeros((0, 3), dtype=np.float32)
    axes = [start[a] + spacing * (0.5 + np.arange(counts[a])) for a in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3).astype(np.float32)


def first_of_each_row_reference(key):
    return np.sort(np.unique(key, axis=0, return_index=True)[1])


def morton_order_reference(points, origin, cell_size):
    cells = np.clip(np.floor((points - origin) / cell_size).astype(np.int64), 0, 1023)
    key = np.zeros(len(points), dtype=np.int64)
    for bit in range(10):
        for axis in range(3):
            key |= ((cells[:, axis] >> bit) & 1) << (3 * bit + axis)
    return np.argsort(key, kind="stable")


@pytest.mark.parametrize("seed", range(20))
def test_fill_block_and_morton_order_match_the_references(seed):
    rng = np.random.default_rng(seed)
    start = rng.uniform(-2, 2, 3)
    end = start + rng.uniform(0, 1.5, 3)
    spacing = rng.uniform(0.03, 0.3)
    got = sampling.fill_block(start, end, spacing)
    assert got.dtype == np.float32 and np.array_equal(got, fill_block_reference(start, end, spacing))
    points = rng.uniform(-1, 3, (int(rng.integers(0, 3000)), 3)).astype(np.float32)
    assert np.array_equal(sampling.morton_order(points, start, spacing), morton_order_reference(points, start, spacing))


@pytest.mark.parametrize("seed", range(20))
def test_first_of_each_row_matches_unique_over_rows(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(0, 2000))
    low, high = [(0, 5), (-3, 3), (-10**6, 10**6), (-2**40, 2**40)][seed % 4]  # the last one does not pack
    key = rng.integers(low, high, (n, 3), dtype=np.int64)
    if n:
        key = np.concatenate([key, key[rng.integers(0, n, n // 2)]])  # repeated rows, later
    assert np.array_equal(sampling._first_of_each_row(key), first_of_each_row_reference(key))


def test_box_walls_sample_each_edge_and_corner_once():
    walls = sampling.sample_box_walls([0, 0, 0], [1.0, 0.5, 0.25], 0.05)
    assert len(np.unique(np.round(walls / 1e-4).astype(np.int64), axis=0)) == len(walls)
    assert len(walls) == 2 * (21 * 11 + 11 * 6 + 21 * 6) - 4 * (21 + 11 + 6) + 8
    periodic = sampling.sample_box_walls([0, 0, 0], [1.0, 0.5, 0.25], 0.05, periodic=("x",))
    assert len(periodic) == 20 * (2 * 11 + 2 * 6 - 4)


def test_importing_the_simulator_does_not_load_trimesh():
    """trimesh takes longer to import than warpsph: only scenes with meshes load it."""
    code = "import sys, warpsph.simulation, warpsph.cli; assert 'trimesh' not in sys.modules, 'trimesh imported'"
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)
