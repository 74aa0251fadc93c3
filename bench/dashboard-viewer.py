#!/usr/bin/env python3
"""Plays N people watching one job in the dashboard: each fetches what the job page fetches
(the job's JSON every second, and a new preview when the merged units changed, at most once
a second, alternating exposure and view as people do), until the job ends or the process is
killed. Prints requests made and bytes read at the end.

    dashboard-viewer.py URL JOB [VIEWERS]
"""
import json
import sys
import threading
import time
import urllib.request

url, job = sys.argv[1].rstrip("/"), sys.argv[2]
viewers = int(sys.argv[3]) if len(sys.argv) > 3 else 3
stats = {"requests": 0, "bytes": 0}
lock = threading.Lock()


def get(path):
    with urllib.request.urlopen(url + path, timeout=30) as r:
        body = r.read()
    with lock:
        stats["requests"] += 1
        stats["bytes"] += len(body)
    return body


def viewer(n):
    shown = None
    while True:
        try:
            j = json.loads(get(f"/api/jobs/{job}"))
        except Exception:
            time.sleep(1)
            continue
        tag = (j["units_done"], j["state"])
        if tag != shown and j["units_done"] > 0:
            view = "noise" if n % 2 and j["state"] != "done" else "color"
            try:
                get(f"/api/jobs/{job}/preview.png?exposure={n % 3}&view={view}")
            except Exception:
                pass
            shown = tag
        if j["state"] in ("done", "failed", "cancelled"):
            return
        time.sleep(1)


threads = [threading.Thread(target=viewer, args=(i,), daemon=True) for i in range(viewers)]
for t in threads:
    t.start()
for t in threads:
    t.join()
print(f"{stats['requests']} requests, {stats['bytes']} bytes")
