"""A shard runner for tests that dies once: `python kill_runner.py SHARD_INDEX SCENES -- RUNNER...`.

run_distributed appends `PRESET --out DIR --shard i/n ...` to the runner command. For shard
SHARD_INDEX on its first attempt (no `<DIR>.killed` marker yet), this starts the real runner, waits
until SCENES of its scenes are complete, kills it (SIGKILL, as a crashed machine would) and exits
non-zero, so the Ray task fails and is retried with --resume. Every other call just runs RUNNER.
"""
import json
import subprocess
import sys
import time
from pathlib import Path


def main(argv):
    sep = argv.index("--")
    shard_index, scenes = int(argv[0]), int(argv[1])
    cmd = argv[sep + 1:]
    out = Path(cmd[cmd.index("--out") + 1])
    i = int(cmd[cmd.index("--shard") + 1].split("/")[0])
    marker = out.parent / (out.name + ".killed")
    proc = subprocess.Popen(cmd)
    if i != shard_index or marker.exists():
        return proc.wait()
    while proc.poll() is None:
        done = 0
        for sj in out.glob("scene.*/scene.json"):
            try:
                done += bool(json.loads(sj.read_text()).get("complete"))
            except (ValueError, OSError):
                pass
        if done >= scenes:
            proc.kill()
            proc.wait()
            marker.write_text(str(done))
            print(f"kill_runner: killed after {done} scene(s)", flush=True)
            return 9
        time.sleep(0.05)
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
