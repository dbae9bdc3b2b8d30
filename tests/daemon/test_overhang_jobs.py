"""A daemon job whose slice has unsupported wall layers over air fails with the slicer's one
line, naming ``hostctl print``'s own options; ``--allow-overhang`` (recorded with the job)
lets it through with the warning in its reason, and ``--seed``/``--parts`` are kept too; the
same file sent again without it is refused at once (the refusal is kept).

The part is a small block with a horizontal bore, whose ceiling is a wall over air whatever
the closed loop tries (as ``tests/cli/test_cli_slice_overhang.py``): one sub-part, sliced in
a fraction of the time of a tee's branch lip (``tests/slicer/test_replay_walls.py``).
"""

from __future__ import annotations

import asyncio
import json
import re
from pathlib import Path

import pytest
from hostd_harness import DaemonProc, hostctl

from hostd.cli.main import build_parser
from slicer.mesh.samples import bored_block
from slicer.repair import ALTERNATIVES  # seeds the closed loop tries after the first

pytestmark = [pytest.mark.asyncio, pytest.mark.slow]


def _print_options() -> set[str]:
    (sub,) = [a for a in build_parser()._actions if getattr(a, "choices", None)
              and "print" in a.choices]
    return {o for a in sub.choices["print"]._actions for o in a.option_strings}


async def test_a_slice_over_air_fails_unless_the_job_allows_it(tmp_path):
    bored = tmp_path / "bored.stl"
    bored_block().export(bored)
    d = DaemonProc(tmp_path)
    await d.start()
    try:
        async with asyncio.timeout(240):
            c = await d.rpc()
            await c.call("events.subscribe", events=["job.state"])
            rc, _, err = await hostctl(d.socket, "queue", "hold")  # the allowed job waits
            assert rc == 0, err
            rc, out, err = await hostctl(d.socket, "print", str(bored), "--wait")
            assert rc == 1, (out, err)
            (line,) = err.strip().splitlines()
            assert re.match(r"hostctl: job 1 failed: slicing failed: bored\.stl: replay found \d+ "
                            r"unsupported wall layers over air .*; refusing to write the file: "
                            r"worst sub-part \d+ layer \d+, [\d.]+% of its \d+ wall points "
                            r"unsupported, around \[.*\] mm \(part frame\); "
                            rf"try --seed {ALTERNATIVES + 1} \(or "
                            r"another seed\), another --parts \(the coarse part count\) or "
                            r"--allow-overhang to write it as it is$", line), line
            assert set(re.findall(r"--[a-z-]+", line)) <= _print_options()

            rc, out, err = await hostctl(d.socket, "print", str(bored), "--allow-overhang",
                                         "--seed", "0", "--json")
            assert rc == 0, err
            job = json.loads(out)
            assert job["allow_overhang"] is True and job["slice_options"] == {"seed": 0}
            ready = await c.until_state(job["id"], "ready", "failed")
            assert ready["new"] == "ready", ready
            got = await c.call("job.get", id=job["id"])
            assert got["allow_overhang"] is True
            assert re.search(r"^sliced; warning: replay found \d+ unsupported wall layers over "
                             r"air .*; written anyway, as asked \(--allow-overhang\): worst "
                             r"sub-part", got["reason"]), got["reason"]
            assert got["info"]["unsupported_wall_layers"] > 0
            rc, out, _ = await hostctl(d.socket, "jobs")
            assert re.search(r"^\s*2\s+ready .* bored\.stl  \[--allow-overhang --seed 0\]",
                             out, re.M), out

            # the same file without the flag: not served from the allowed job's cache, but
            # refused at once from job 1's refusal, kept with the cache
            hits = (await c.call("printer.status"))["slicer"]["cache_hits"]
            again = await c.call("job.submit", name="bored.stl", data=_b64(bored))
            failed = await c.until_state(again["id"], "ready", "failed")
            assert failed["new"] == "failed" and "--allow-overhang" in failed["reason"]
            assert (await c.call("printer.status"))["slicer"]["cache_hits"] == hits + 1
            assert (await c.call("job.get", id=again["id"]))["reason"].endswith(
                line.removeprefix("hostctl: job 1 failed: "))
            for bad, message in ((dict(seed=-1), "seed: -1 must lie in [0, 2147483647]"),
                                 (dict(parts=65), "parts: 65 must lie in [0, 64]")):
                with pytest.raises(Exception, match=re.escape(message)):
                    await c.call("job.submit", name="bored.stl", data=_b64(bored), **bad)
            await c.close()
    finally:
        assert await d.stop() == 0
    assert d.loop_errors() == []


def _b64(path: Path) -> str:
    import base64

    return base64.b64encode(path.read_bytes()).decode()
