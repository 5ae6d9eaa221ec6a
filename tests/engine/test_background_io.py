"""ReadAhead and WriteBehind: reads of the next index and writes of the last one run in one background
thread; values, order and errors are those of the calls themselves."""
from __future__ import annotations

import threading

import pytest

from rvr_addon.io.readahead import ReadAhead


def test_values_come_ahead_in_one_background_thread_and_in_order():
    threads, order = [], []

    def read(i):
        threads.append(threading.current_thread().name)
        order.append(i)
        return i * 10

    ra = ReadAhead(read)
    got = [ra.get(i, i + 1 if i < 4 else None) for i in range(5)]
    ra.close()
    assert got == [0, 10, 20, 30, 40] and order == [0, 1, 2, 3, 4]
    assert ra.ahead == 4 and threads[0] == threading.current_thread().name
    assert all(t.startswith("rvr-readahead") for t in threads[1:])


def test_another_key_than_read_ahead_is_read_now_and_errors_surface_only_when_asked_for():
    def read(i):
        if i == 2:
            raise ValueError("frame 2 is corrupt")
        return i

    ra = ReadAhead(read)
    assert ra.get(0, then=2) == 0
    assert ra.get(5, then=None) == 5  # the failed read ahead of 2 was never asked for: no error
    assert ra.get(1, then=2) == 1
    with pytest.raises(ValueError, match="frame 2"):
        ra.get(2)
    ra.get(3, then=4)
    ra.close()
    assert ra.get(4) == 4 and ra.ahead == 0


def test_writes_run_behind_one_at_a_time_in_order_and_an_error_stops_the_next_submit():
    import time

    from rvr_addon.io.writebehind import WriteBehind

    done, running = [], []

    def write(i):
        running.append(i)
        assert len(running) == 1  # never two at once
        time.sleep(0.01)
        if i == 3:
            running.clear()
            raise OSError("No space left on device: frame 3")
        done.append(i)
        running.clear()

    wb = WriteBehind()
    for i in range(3):
        wb.submit(write, i)
    wb.wait()
    assert done == [0, 1, 2] and wb.submitted == 3
    wb.submit(write, 3)
    with pytest.raises(OSError, match="frame 3"):
        wb.submit(write, 4)  # the previous write's error, before 4 starts
    assert 4 not in done
    wb.submit(write, 5)
    wb.close()
    assert done == [0, 1, 2, 5]
    wb.submit(write, 3)
    with pytest.raises(OSError, match="frame 3"):
        wb.close()


def test_finish_hands_the_last_error_back():
    from rvr_addon.io.writebehind import WriteBehind

    def fail():
        raise OSError("read-only file system")

    wb = WriteBehind()
    assert wb.finish() is None
    wb.submit(fail)
    err = wb.finish()
    assert isinstance(err, OSError) and "read-only" in str(err)
