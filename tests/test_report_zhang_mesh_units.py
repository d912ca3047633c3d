"""The ``zhang_mesh`` study as independently scheduled and cached units (``zhang_mesh.units``, ``cases.SPLIT``,
``accuracy.run_report``): one per (case, element, level) solve, at the test suite's ("tiny") sweep. Combined, they
give the study the one-process run gives, serially and as Dask tasks on two workers; a rerun reuses every unit
whose file is there and recomputes only the missing one."""
from __future__ import annotations

import json
import shutil

import pytest

from tissuerender.report import accuracy, cases, zhang_mesh

SWEEP = zhang_mesh.SWEEPS["tiny"]


def _numbers(study: dict) -> dict:
    """The study without what differs between two runs of the same arithmetic (wall times, cache markers)."""
    def strip(value):
        if isinstance(value, dict):
            return {k: strip(v) for k, v in value.items() if k not in ("wall_s", "cached", "computed_wall_s", "units")}
        if isinstance(value, list):
            return [strip(v) for v in value]
        return value

    return strip(study)


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    out = tmp_path_factory.mktemp("zhang_mesh_units")
    return out, accuracy.run_report(out, cases=[zhang_mesh.CASE], level="tiny", stages=False)


def test_the_study_is_one_unit_per_case_element_and_level_each_cached_in_its_own_file(serial):
    out, report = serial
    listed = zhang_mesh.units(SWEEP)
    ids = [zhang_mesh.unit_id(u) for u in listed]
    expected = {(name, element, level) for name in SWEEP["cases"] for element, key in zhang_mesh.LEVEL_KEYS.items()
                for level in SWEEP[key]}
    assert {(u["case"], u["element"], u["level"]) for u in listed} == expected and len(ids) == len(set(ids))
    assert cases.work_units(zhang_mesh.CASE, SWEEP) == len(listed)  # one tick of the progress bar per unit
    # the most refined first: a quadratic level has the nodes of the next linear level
    refinement = [u["level"] + (u["element"] == "quadratic") for u in listed]
    assert refinement == sorted(refinement, reverse=True)
    study = report["cases"][zhang_mesh.CASE]
    assert list(study["units"]) == ids and not any(u["cached"] for u in study["units"].values())
    assert sorted(p.stem for p in (out / "cases" / zhang_mesh.CASE).glob("*.json")) == sorted(ids)


def test_the_units_combined_give_the_one_process_study(serial):
    _, report = serial
    study = report["cases"][zhang_mesh.CASE]
    one_process = accuracy.finite_json(zhang_mesh.run_zhang_mesh(SWEEP))
    assert _numbers(study) == _numbers(one_process)
    assert study["measures"] == one_process["measures"]
    # the expectations of test_report_zhang_mesh.py hold on the combined study
    cube = study["cases"]["cube_shear"]
    assert cube["converged"]["line_u_m"] == cube["quadratic"][-1]["line_u_m"] and cube["quadratic"][-1]["line_max_m"] == 0.0
    assert cube["quadratic"][0]["line_rmse_m"] < cube["linear"][1]["line_rmse_m"]
    assert cube["linear_anp"][1]["line_rmse_m"] < cube["linear"][1]["line_rmse_m"]
    assert study["measures"]["cube_shear_linear_line_max_m"] == cube["linear"][0]["line_max_m"] > 0.0


def test_a_rerun_recomputes_only_the_missing_unit(serial, tmp_path):
    out, report = serial
    shutil.copytree(out / "cases", tmp_path / "cases")
    folder = tmp_path / "cases" / zhang_mesh.CASE
    missing = "cube_shear-quadratic-1"
    present = json.loads((folder / "cube_shear-linear-0.json").read_text())
    (folder / f"{missing}.json").unlink()
    again = accuracy.run_report(tmp_path, cases=[zhang_mesh.CASE], level="tiny", stages=False)["cases"][zhang_mesh.CASE]
    assert again["cached"] is False  # not every unit was reused
    assert {i for i, u in again["units"].items() if not u["cached"]} == {missing}
    assert (folder / f"{missing}.json").is_file()
    assert json.loads((folder / "cube_shear-linear-0.json").read_text()) == present  # reused, not rewritten
    assert _numbers(again) == _numbers(report["cases"][zhang_mesh.CASE])
    third = accuracy.run_report(tmp_path, cases=[zhang_mesh.CASE], level="tiny", stages=False)["cases"][zhang_mesh.CASE]
    assert third["cached"] is True and all(u["cached"] for u in third["units"].values())


def test_the_units_on_two_dask_workers_give_the_serial_study(serial, tmp_path):
    from distributed import Client

    _, report = serial
    # in-process workers (threads): the Dask path's scheduling, caching and combining without spawning processes
    with Client(processes=False, n_workers=2, threads_per_worker=1, dashboard_address=":0") as client:
        on_dask = accuracy.run_report(tmp_path, cases=[zhang_mesh.CASE], level="tiny", stages=False,
                                      client=client)["cases"][zhang_mesh.CASE]
    assert on_dask["cached"] is False and list(on_dask["units"]) == list(report["cases"][zhang_mesh.CASE]["units"])
    assert _numbers(on_dask) == _numbers(report["cases"][zhang_mesh.CASE])
    assert sorted(p.stem for p in (tmp_path / "cases" / zhang_mesh.CASE).glob("*.json")) == sorted(on_dask["units"])
