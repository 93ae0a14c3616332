"""The packing cache (geodem.build.jam_cache): a jam repeated with the same inputs returns the
very bits of the first, anything changed jams anew, and the cache can be turned off."""
import numpy as np
import pytest

from geodem.build import jam_cache
from geodem.build.isotropic import jam, jam_fresh


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GEODEM_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("GEODEM_PACKING_CACHE", raising=False)
    return tmp_path / "packings"


def _radii(n=40, seed=3):
    return np.random.default_rng(seed).uniform(0.4, 0.6, n)


LO, HI = np.zeros(2), np.array([6.0, 6.0])


def test_a_repeated_jam_is_read_back_bit_for_bit(cache):
    x1, r1, info1 = jam(_radii(), LO, HI, seed=5)
    assert info1["cached"] is False and len(list(cache.glob("*.npz"))) == 1
    x2, r2, info2 = jam(_radii(), LO, HI, seed=5)
    assert info2["cached"] is True
    assert x2.tobytes() == x1.tobytes() and r2.tobytes() == r1.tobytes()
    assert {k: info2[k] for k in info1 if k != "cached"} == \
        {k: info1[k] for k in info1 if k != "cached"}
    # and the cache gives what jamming gives
    x3, r3, _ = jam_fresh(_radii(), LO, HI, seed=5)
    assert x3.tobytes() == x1.tobytes() and r3.tobytes() == r1.tobytes()


@pytest.mark.parametrize("change", ["seed", "radii", "box", "overlap"])
def test_any_changed_input_jams_anew(cache, change):
    jam(_radii(), LO, HI, seed=5)
    args = {"r0": _radii(), "lo": LO, "hi": HI, "seed": 5}
    if change == "seed":
        args["seed"] = 6
    elif change == "radii":
        args["r0"] = _radii(seed=4)
    elif change == "box":
        args["hi"] = np.array([6.0, 6.5])
    else:
        args["overlap"] = 0.02
    _, _, info = jam(args.pop("r0"), args.pop("lo"), args.pop("hi"), **args)
    assert info["cached"] is False and len(list(cache.glob("*.npz"))) == 2


def test_the_cache_can_be_turned_off_and_a_broken_file_is_a_miss(cache, monkeypatch):
    monkeypatch.setenv("GEODEM_PACKING_CACHE", "0")
    jam(_radii(), LO, HI, seed=5)
    _, _, info = jam(_radii(), LO, HI, seed=5)
    assert info["cached"] is False and not cache.exists()
    monkeypatch.setenv("GEODEM_PACKING_CACHE", "1")
    x1, _, _ = jam(_radii(), LO, HI, seed=5)
    (path,) = cache.glob("*.npz")
    path.write_bytes(b"not a packing")
    x2, _, info = jam(_radii(), LO, HI, seed=5)
    assert info["cached"] is False and x2.tobytes() == x1.tobytes()
    assert jam(_radii(), LO, HI, seed=5)[2]["cached"] is True  # rewritten whole
    path.write_bytes(path.read_bytes()[:200])  # a file cut short (a full disc, a crash)
    x3, _, info = jam(_radii(), LO, HI, seed=5)
    assert info["cached"] is False and x3.tobytes() == x1.tobytes()


def test_the_cache_keeps_at_most_max_files(cache, monkeypatch):
    monkeypatch.setattr(jam_cache, "MAX_FILES", 2)
    for seed in (1, 2, 3):
        jam(_radii(), LO, HI, seed=seed)
    assert len(list(cache.glob("*.npz"))) == 2
    assert not list(cache.glob("*.tmp*"))
