"""models.batch.BatchError crosses process boundaries (pickle; the engine helper processes use it)."""

from __future__ import annotations

import pickle
from concurrent.futures import ProcessPoolExecutor

import pytest

from models.batch import BatchError, SensorBatch


class Narrower(BatchError):
    pass


@pytest.mark.parametrize("cls", [BatchError, Narrower])
def test_batch_error_pickles_with_field_and_problem(cls: type[BatchError]) -> None:
    exc = cls("acc_t_ns", "timestamps must increase")
    back = pickle.loads(pickle.dumps(exc, protocol=pickle.HIGHEST_PROTOCOL))
    assert type(back) is cls and isinstance(back, ValueError)
    assert (back.field, back.problem, str(back)) == ("acc_t_ns", "timestamps must increase", str(exc))


def _refuse() -> None:
    SensorBatch(acc_t_ns=[0, 1], acc=[[0.0, 0.0, 1.0]]).validate()  # 2 timestamps, 1 row


def test_batch_error_raised_in_another_process_arrives_intact() -> None:
    with pytest.raises(BatchError) as local:
        _refuse()
    with ProcessPoolExecutor(max_workers=1) as pool:
        with pytest.raises(BatchError) as remote:
            pool.submit(_refuse).result()
    assert (remote.value.field, remote.value.problem) == (local.value.field, local.value.problem)
