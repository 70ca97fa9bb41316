import os

import numpy as np
import pytest

if os.environ.get("PYTEST_XDIST_WORKER"):
    from threadpoolctl import threadpool_limits

    # Parallel workers share the cores: BLAS threads on top of them only oversubscribe.
    _ONE_BLAS_THREAD = threadpool_limits(limits=1, user_api="blas")
    # Workers start with COLUMNS=80 set; CLI output is then wrapped as on an 80-column terminal, which a pipe
    # (what the tests stand for) is not.
    for _name in ("COLUMNS", "LINES"):
        os.environ.pop(_name, None)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
