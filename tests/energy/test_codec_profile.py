from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from energy import codec
from energy.profile import BehaviourCalibration, Profile

arrays = hnp.arrays(
    dtype=st.sampled_from([np.float64, np.int64, np.bool_, np.float32]),
    shape=hnp.array_shapes(min_dims=0, max_dims=3, max_side=5),
)


@given(a=arrays, x=st.floats(allow_nan=False), s=st.text(max_size=20))
def test_codec_round_trip(a: np.ndarray, x: float, s: str) -> None:
    state = {"a": a, "nested": {"x": x, "s": s, "l": [1, None, True]}}
    out = codec.loads(codec.dumps(state))
    assert out["a"].dtype == a.dtype and out["a"].shape == a.shape
    np.testing.assert_array_equal(out["a"], a)
    assert out["nested"] == {"x": x, "s": s, "l": [1, None, True]}


@given(a=arrays.filter(lambda a: a.ndim >= 2))
def test_codec_round_trips_non_contiguous_views(a: np.ndarray) -> None:
    for view in (a.T, a[::2], a[:, ::-1]):
        out = codec.loads(codec.dumps({"v": view}))["v"]
        assert out.shape == view.shape
        np.testing.assert_array_equal(out, view)


def test_codec_encodes_the_same_bytes_twice() -> None:
    state = {"a": np.arange(6.0).reshape(2, 3), "b": np.zeros((2, 3)), "c": np.ones(4, dtype=np.int64)}
    assert codec.dumps(state) == codec.dumps(state)


@pytest.mark.parametrize("blob", [b"", b"garbage", b"\x80\x04pickle"])
def test_codec_refuses_foreign_bytes(blob: bytes) -> None:
    with pytest.raises(ValueError, match="header"):
        codec.loads(blob)


def test_codec_refuses_object_arrays() -> None:
    with pytest.raises(TypeError):
        codec.dumps({"a": np.array([object()])})


def test_profile_round_trip_and_validation() -> None:
    p = Profile({"walk": BehaviourCalibration(step_model={"k": [0.1, 0.2]}, sigma_d_m=0.04, n_steps=25, calibrated=True)})
    assert Profile.from_dict(p.to_dict()).to_dict() == p.to_dict()
    assert p.is_calibrated("walk") and not p.is_calibrated("run")
    with pytest.raises(ValueError, match="unknown behaviour 'fly'"):
        Profile.from_dict({"behaviours": {"fly": {}}})
    with pytest.raises(ValueError, match="walk: unknown calibration fields"):
        Profile.from_dict({"behaviours": {"walk": {"bogus": 1}}})
    with pytest.raises(ValueError, match="version"):
        Profile.from_dict({"version": 99})
