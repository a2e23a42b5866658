"""scripts/accelerator_check.sh writes its JSON even when its time budget runs out (issue 31)."""

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_an_exhausted_budget_skips_every_step_and_still_writes_the_json(tmp_path):
    out = tmp_path / "check.json"
    env = dict(os.environ, TOTAL_S="20", PYTHON=sys.executable, JAX_PLATFORMS="cpu")
    r = subprocess.run(["bash", "scripts/accelerator_check.sh", str(out)], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    res = json.loads(out.read_text())
    assert set(res["steps"]) >= {"pqrm", "bsp", "qlink", "hssh", "study_full"}
    assert all(s == {"skipped": "TOTAL_S exhausted"} for s in res["steps"].values())
    assert res["all_ok"] is False and res["total_budget_s"] == 20.0
    assert res["env"]["backend"] == "cpu"
