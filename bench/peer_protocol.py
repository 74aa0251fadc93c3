"""The peer's side of `tessera bench --peer-command` (crates/cli/src/bench/peer.rs), for peers
written in Python (bench/mitsuba_peer.py, bench/cycles_peer.py).

tessera writes `SCENE SPP SEED` lines; the peer answers each with zero or more CSV rows and
then `done`. A line `error: MESSAGE` ends the run with that message.
"""
import sys


def requests(lines=None):
    """Yields each `SCENE SPP SEED` request read from `lines` (stdin) as (scene, spp, seed),
    and writes `done` when the caller asks for the next one (so the caller's rows for a request
    come before it); a malformed line is answered with `error: …` instead."""
    for line in sys.stdin if lines is None else lines:
        fields = line.split()
        try:
            name, spp, seed = fields[0], int(fields[1]), int(fields[2])
            if len(fields) != 3 or spp < 1 or seed < 0:
                raise ValueError
        except (ValueError, IndexError):
            print(f"error: expected `SCENE SPP SEED`, got {line.strip()!r}", flush=True)
            continue
        yield name, spp, seed
        print("done", flush=True)
