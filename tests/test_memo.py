"""kincal._memo.remember: the one insertion rule of kincal's bounded memories (joint-screw terms and frames,
exactness verdicts, arm values per model, layout blocks and selections, column plans)."""

import threading

from kincal._memo import remember


def test_oldest_entry_goes_first_at_the_limit():
    cache: dict = {}
    for k in range(5):
        assert remember(cache, k, k * 10, 3) == k * 10
    assert list(cache.items()) == [(2, 20), (3, 30), (4, 40)]


def test_a_cache_another_thread_emptied_meanwhile_takes_the_entry():
    cache: dict = {}
    remember(cache, "a", 1, 0)  # at its limit while empty: nothing to drop, no error
    assert cache == {"a": 1}


def test_threads_inserting_at_once_never_raise_and_stay_near_the_limit():
    cache: dict = {}
    errors: list = []

    def insert(start: int) -> None:
        try:
            for k in range(start, start + 20000):
                remember(cache, k, k, 8)
        except Exception as exc:  # noqa: BLE001 - any error is the failure this test looks for
            errors.append(exc)

    threads = [threading.Thread(target=insert, args=(100000 * i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert len(cache) <= 8 + len(threads)
