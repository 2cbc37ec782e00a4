"""Trajectory uploads are bounded by what a trajectory is (issue 16, finding 1): a small zip
of a huge array is refused from its headers, before anything is unpacked, and a stored file
too big for JSON is refused as JSON (the .npz is streamed)."""

from __future__ import annotations

import base64
import io
import time
import tracemalloc

import numpy as np
import pytest

from app.service import artifacts
from app.service.errors import InvalidInput, PayloadTooLarge


def npz(compressed: bool = False, **arrays) -> bytes:
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    return buf.getvalue()


def test_a_simulator_trajectory_passes(tmp_path):
    from app.sim import rollout

    res = rollout("throw", np.full((10, 12), 50e3), release_step=5, preset="fast", record_qpos=True)
    res.trajectory.to_npz(tmp_path / "t.npz")
    shapes = artifacts.check_npz((tmp_path / "t.npz").read_bytes())
    assert shapes["qpos"][1] == 61 and shapes["bend_rad"][1:] == (3, 2)


def test_a_small_zip_of_a_huge_array_is_refused_without_unpacking_it():
    raw = npz(compressed=True, tip_speed_m_s=np.zeros(16 * 1024 * 1024))  # 128 MB of zeros
    assert len(raw) < 200_000
    tracemalloc.start()
    t0 = time.perf_counter()
    with pytest.raises(PayloadTooLarge, match="at most 50000 samples"):
        artifacts.decode_npz_b64(base64.b64encode(raw).decode(), max_bytes=16 * 1024 * 1024)
    elapsed = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert elapsed < 0.5 and peak < 5 * 1024 * 1024  # headers only, not 128 MB


@pytest.mark.parametrize(
    ("arrays", "error", "words"),
    [
        ({"qpos": np.zeros((10, 500))}, PayloadTooLarge, "numbers each"),
        ({"x": np.zeros((2, 2, 2, 2))}, InvalidInput, "4 dimensions"),
        ({"x": np.zeros(())}, InvalidInput, "0 dimensions"),
        ({"names": np.array(["a", "b"])}, InvalidInput, "only numbers"),
        ({f"a{i}": np.zeros(3) for i in range(40)}, PayloadTooLarge, "at most 32"),
        (
            {f"a{i}": np.zeros((50_000, 100)) for i in range(3)},
            PayloadTooLarge,
            "unpacks to",
        ),
    ],
)
def test_shapes_no_trajectory_has_are_refused(arrays, error, words):
    with pytest.raises(error, match=words):
        artifacts.check_npz(npz(compressed=True, **arrays))


def test_pickles_and_garbage_are_refused():
    buf = io.BytesIO()
    np.save(buf, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(InvalidInput):
        artifacts.check_npz(buf.getvalue())
    with pytest.raises(InvalidInput, match="not a NumPy"):
        artifacts.check_npz(b"PK\x03\x04 not really")


def test_json_of_a_stored_file_too_big_for_it_is_refused(tmp_path, monkeypatch):
    path = tmp_path / "t.npz"
    path.write_bytes(npz(time_s=np.arange(1000.0), qpos=np.zeros((1000, 61))))
    assert len(artifacts.npz_to_json(path)["qpos"]) == 1000
    monkeypatch.setattr(artifacts, "MAX_JSON_VALUES", 10_000)
    with pytest.raises(PayloadTooLarge, match="format=npz"):
        artifacts.npz_to_json(path)
