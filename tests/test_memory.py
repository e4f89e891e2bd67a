import subprocess
import sys
import textwrap

import pytest

from core.memory import peak_mb, release_free_memory

# A child process: arrays of 100 kB (under glibc's mmap threshold) made and freed in a thread land in that
# thread's own heap, which keeps their pages; the last one stays alive, so the heap cannot shrink from its top.
_CHILD = textwrap.dedent(
    """
    import sys, threading
    import numpy as np
    sys.path.insert(0, {root!r})
    from core.memory import release_free_memory

    def rss():
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024

    keep = []
    def work():
        arrays = [np.ones(12_800) for _ in range(3000)]  # 300 MB
        keep.append(arrays[-1])
    t = threading.Thread(target=work)
    t.start()
    t.join()
    before = rss()
    release_free_memory()
    print(before, rss())
    """
)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's heaps: Linux")
def test_release_free_memory_gives_freed_pages_back(tmp_path):
    import os

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out = subprocess.run([sys.executable, "-c", _CHILD.format(root=root)], capture_output=True, text=True, check=True)
    before, after = map(float, out.stdout.split())
    assert before - after > 200, (before, after)


def test_release_free_memory_and_peak_run_anywhere():
    release_free_memory()
    peak = peak_mb()
    assert peak is None or peak > 10
