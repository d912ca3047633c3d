"""The dashboard line ``render --workers N`` prints (issue 20 item 1): the address answers HTTP, and the local
cluster's workers do not inherit Dask's MALLOC_TRIM_THRESHOLD_ (which costs a frame +45 % CPU, docs/dask.md)."""
import os
import re
import urllib.request

import pytest

pytest.importorskip("distributed")
pytest.importorskip("bokeh", reason="the dashboard needs bokeh (pip install 'bokeh>=3.1')")

from tissuerender.distributed import dask_client  # noqa: E402


def test_printed_dashboard_address_answers_http_and_workers_keep_glibc_adaptive_malloc():
    lines = []
    before = dict(os.environ)
    with dask_client(workers=1, announce=lines.append) as client:
        (line,) = lines
        match = re.search(r"dashboard: (http://\S+)", line)
        assert match, line
        with urllib.request.urlopen(match.group(1), timeout=20) as response:
            assert response.status == 200
            assert b"<html" in response.read(4096).lower()
        # os.getenv, not a function of this module: the worker need not import tissuerender to run it
        (trim,) = client.run(os.getenv, "MALLOC_TRIM_THRESHOLD_").values()
        (threads,) = client.run(os.getenv, "NUMBA_NUM_THREADS").values()
        assert trim == before.get("MALLOC_TRIM_THRESHOLD_")
        assert threads == str(max(1, os.cpu_count() or 1))
    assert dict(os.environ) == before  # the nannies' pre-spawn variables do not stay in the client's environment
