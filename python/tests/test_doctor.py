"""cnfmp.doctor: the checks behind `cnfmp doctor`, on this venv and on simulated breakage."""

import importlib.metadata
import json

import pytest

from cnfmp import doctor


@pytest.fixture(scope="module")
def report():
    return json.loads(doctor.collect())


def test_every_check_passes_on_the_project_venv(report):
    failed = [c for c in report["checks"] if not c["ok"]]
    assert not failed, failed
    assert report["python"]["prefix"] != report["python"]["base_prefix"]


def test_pinned_versions_are_reported(report):
    by_name = {c["name"]: c for c in report["checks"]}
    assert by_name["torch"]["detail"].startswith("2.10.")
    assert by_name["mujoco"]["detail"].startswith("4.0.0")
    assert by_name["lerobot"]["detail"].startswith("0.4.4")
    assert by_name["mujoco render"]["backend"] in ("egl", "osmesa")


def test_a_wrong_version_fails_with_the_fix(monkeypatch):
    real = importlib.metadata.version
    monkeypatch.setattr(doctor.metadata, "version", lambda name: "2.9.1" if name == "torch" else real(name))
    torch = next(c for c in doctor._requirement_checks() if c["name"] == "torch")
    assert not torch["ok"]
    assert torch["detail"] == "2.9.1 (requires ==2.10.*)"
    assert "make setup" in torch["fix"]


def test_a_missing_package_fails(monkeypatch):
    real = importlib.metadata.version

    def version(name):
        if name == "mujoco":
            raise importlib.metadata.PackageNotFoundError(name)
        return real(name)

    monkeypatch.setattr(doctor.metadata, "version", version)
    mujoco = next(c for c in doctor._requirement_checks() if c["name"] == "mujoco")
    assert (mujoco["ok"], mujoco["detail"]) == (False, "not installed")


def test_osmesa_fallback_renders_in_a_child_process():
    result = doctor._probe_render("osmesa", in_process=False)
    assert result["ok"], result
    assert result["red"] > 100


def test_an_unusable_backend_reports_its_error():
    result = doctor._probe_render("no-such-backend", in_process=False)
    assert not result["ok"]
    assert result["error"]
