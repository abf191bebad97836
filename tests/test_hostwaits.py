"""hbeo.model.hostwaits: the host's waits for a CUDA device, counted at the project's own line that led to each."""
import warnings

import pytest
import torch

from hbeo.model.hostwaits import MESSAGE, host_waits

#: a library's function (a file outside the repository) that makes torch's warning, as a torch op would
LIBRARY = {}
exec(compile(f"import warnings\ndef op():\n    warnings.warn({MESSAGE + ' (Triggered internally)'!r})\n",
             "/elsewhere/library.py", "exec"), LIBRARY)


def read_back():
    LIBRARY["op"]()                                    # the line a wait is counted at


def test_each_wait_is_counted_at_the_project_s_innermost_line_and_other_warnings_still_show():
    with host_waits("cpu") as waits:
        for _ in range(3):
            read_back()
        with pytest.warns(UserWarning, match="something else"):
            warnings.warn("something else")
    line = read_back.__code__.co_firstlineno + 1
    assert waits == {f"tests/test_hostwaits.py:{line} read_back": 3}
    with warnings.catch_warnings(record=True) as seen:  # outside the block: a plain warning again, not counted
        warnings.simplefilter("always")
        read_back()
    assert len(seen) == 1 and waits == {f"tests/test_hostwaits.py:{line} read_back": 3}


def test_a_wait_with_no_project_line_on_its_stack_is_named_by_its_innermost_frame():
    import threading
    with host_waits("cpu") as waits:
        t = threading.Thread(target=LIBRARY["op"])      # a thread's stack: threading's frames, then the library's
        t.start()
        t.join()
    assert list(waits) == ["/elsewhere/library.py:3 op"]


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_a_read_of_a_device_value_is_one_wait_and_the_mode_is_set_back():
    x = torch.ones(4, device="cuda")
    before = torch.cuda.get_sync_debug_mode()
    with host_waits("cuda") as waits:
        x.sum().item()
        y = x * 2                                       # queued: no wait
    assert sum(waits.values()) == 1 and torch.cuda.get_sync_debug_mode() == before
    assert all(s.startswith("tests/test_hostwaits.py:") for s in waits)
    del y
