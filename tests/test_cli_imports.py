"""Start-up: a command pays only for the imports it uses.

`pimbs --help` and `pimbs info` answer in a fraction of a second because they never import
torch; `pimbs train` imports torch but not its compile machinery (torch._dynamo, sympy),
which torch.optim would pull in and which costs seconds on a small CPU. Checked in a fresh
interpreter, since the test process itself has imported everything.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "two_link_sim.parquet"

_RUN = """
import json, sys
from pimbs_cli.main import main

def modules_after(*args):
    try:
        main(list(args), standalone_mode=False)
    except SystemExit:
        pass
    return {name: name in sys.modules for name in ("torch", "torch._dynamo", "sympy")}

seen = {"help": modules_after("--help"), "info": modules_after("info", sys.argv[1])}
seen["train"] = modules_after("train", sys.argv[1], "--n-train", "12", "--epochs", "2",
                              "--hidden", "8", "--threads", "1")
print(json.dumps(seen))
"""


def test_help_and_info_never_import_torch_and_train_skips_the_compiler() -> None:
    out = subprocess.run([sys.executable, "-c", _RUN, str(FIXTURE)], capture_output=True,
                         text=True, check=True)
    seen = json.loads(out.stdout.strip().splitlines()[-1])
    assert seen["help"] == {"torch": False, "torch._dynamo": False, "sympy": False}
    assert seen["info"] == {"torch": False, "torch._dynamo": False, "sympy": False}
    assert seen["train"] == {"torch": True, "torch._dynamo": False, "sympy": False}
