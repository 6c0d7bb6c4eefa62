"""The RL Baselines3 Zoo on this project's ids, with one torch thread on small machines::

    python -m panda_grasp_env.commands.zoo train --algo tqc --env PandaPush-v0 -conf configs/zoo/tqc.yml ...
    python -m panda_grasp_env.commands.zoo enjoy --algo tqc --env PandaPush-v0 -f logs --no-render ...
    python -m panda_grasp_env.commands.zoo record_video --algo tqc --env PandaPush-v0 -f logs -n 500

Each runs ``python -m rl_zoo3.<script>`` with the same arguments, after

- importing ``panda_grasp_env``, which registers its ids: ``rl_zoo3.record_video`` has no ``--gym-packages``
  and so cannot find them on its own (``train`` and ``enjoy`` also get ``--gym-packages panda_grasp_env``);
- on a machine with at most ``SMALL_MACHINE_CORES`` cores, one torch thread per process unless
  ``--num-threads N`` is given: torch's default of one thread per core made TQC updates 7.5x slower on a loaded
  2-core machine (``train`` and ``enjoy`` take ``--num-threads``; ``record_video`` gets the thread count set
  before it starts).

A Zoo log folder is trusted input: its model zip is a pickle, and ``record_video`` reads its ``args.yml`` with
YAML's unsafe loader.  Play only folders you made.
"""

from __future__ import annotations

import os
import runpy
import sys

#: The scripts of ``rl_zoo3`` this command runs.
SCRIPTS = ("train", "enjoy", "record_video")
#: Machines with at most this many cores get one torch thread per process by default.
SMALL_MACHINE_CORES = 2


def default_threads(argv: list[str], cores: int | None) -> int | None:
    """The torch threads to use when ``argv`` names none (``--num-threads``): 1 on a machine of at most
    ``SMALL_MACHINE_CORES`` cores, else None (torch's own default)."""
    if any(a == "--num-threads" or a.startswith("--num-threads=") for a in argv):
        return None
    return 1 if (cores or 1) <= SMALL_MACHINE_CORES else None


def zoo_argv(script: str, argv: list[str], cores: int | None) -> list[str]:
    """The arguments for ``rl_zoo3.<script>``: ``argv`` with ``--gym-packages panda_grasp_env`` and the default
    thread count added where the script takes them and ``argv`` has none."""
    argv = list(argv)
    if script in ("train", "enjoy"):
        if not any(a == "--gym-packages" or a.startswith("--gym-packages=") for a in argv):
            argv += ["--gym-packages", "panda_grasp_env"]
        threads = default_threads(argv, cores)
        if threads is not None:
            argv += ["--num-threads", str(threads)]
    return argv


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] not in SCRIPTS:
        print(
            f"usage: python -m panda_grasp_env.commands.zoo {{{','.join(SCRIPTS)}}} [rl_zoo3 arguments]\n\n{__doc__}",
            file=sys.stderr,
        )
        return 2
    script, rest = argv[0], argv[1:]
    import panda_grasp_env  # noqa: F401  (registers the ids in this process)

    threads = default_threads(rest, os.cpu_count())
    if threads is not None:
        print(f"torch threads: {threads} ({os.cpu_count()} cores here; --num-threads N to choose)")
    if script == "record_video":
        if "--num-threads" in rest[:-1]:  # record_video has no such flag: this command applies it
            at = rest.index("--num-threads")
            if not rest[at + 1].isdigit() or int(rest[at + 1]) < 1:
                print(f"error: --num-threads must be a whole number >= 1, got {rest[at + 1]!r}", file=sys.stderr)
                return 2
            threads, rest = int(rest[at + 1]), rest[:at] + rest[at + 2 :]
        if threads is not None:
            import torch

            torch.set_num_threads(threads)
    sys.argv = [f"rl_zoo3.{script}", *zoo_argv(script, rest, os.cpu_count())]
    runpy.run_module(f"rl_zoo3.{script}", run_name="__main__", alter_sys=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
