"""Submissions: the exported frames' way to the farm and back, off Blender's main thread.

A `Submission` runs its network work (uploads, submitting each frame, watching the jobs and
fetching their EXRs) on a thread of its own, so Blender never waits on the farm. The thread
touches no Blender data: it posts what happened to a queue, and `tick()`, which Blender's timer
calls on the main thread, applies it (a frame's progress, its error, loading a finished EXR).
"""

import os
import queue
import threading
import time

from .client import FarmError

# How often a running submission asks the coordinator for its jobs' states.
POLL_S = 1.0
# How long a submission keeps asking a coordinator it cannot reach (one that restarts keeps its
# jobs) before it gives up watching; the jobs go on either way.
UNREACHABLE_S = 300.0


class FrameJob:
    """One frame's job as the UI shows it. Written on the main thread only."""

    def __init__(self, number):
        self.number = number
        self.job_id = ""
        self.state = "uploading"
        self.units_done = 0
        self.units_total = 0
        self.error = ""
        self.path = ""


class Submission:
    """One press of "Render on tessera": a job per frame, from upload to the saved EXR."""

    def __init__(self, farm, folder, frames, spp, output_dir, stem):
        self.farm = farm
        self.folder = folder
        self.spp = spp
        self.output_dir = output_dir
        self.stem = stem
        self.exported = frames
        self.frames = [FrameJob(f.number) for f in frames]
        self.error = ""
        self.finished = False
        self.events = queue.Queue()
        self._cancel = threading.Event()
        self._thread = threading.Thread(target=self._run, name="tessera-submission", daemon=True)

    def start(self):
        self._thread.start()

    def cancel(self):
        """Asks the thread to cancel every job still running and stop."""
        self._cancel.set()

    def progress(self):
        """Units merged over units in all, over every frame (0 before any job is known)."""
        total = sum(f.units_total for f in self.frames)
        return sum(f.units_done for f in self.frames) / total if total else 0.0

    def summary(self):
        """One line for the panel."""
        if self.error:
            return self.error
        states = [f.state for f in self.frames]
        done = states.count("done")
        if self.finished:
            failed = len(self.frames) - done
            return f"{done} of {len(self.frames)} frames rendered" + (f", {failed} not" if failed else "")
        return f"{done} of {len(self.frames)} frames done, {int(100 * self.progress())}% of the units"

    # The thread's side: network only, and every outcome posted as an event.

    def _post(self, *event):
        self.events.put(event)

    def _run(self):
        try:
            jobs = self._submit_all()
            self._watch(jobs)
        except FarmError as e:
            self._post("error", str(e))
        except OSError as e:
            self._post("error", f"cannot read or write a file: {e}")
        except Exception as e:  # a reply the add-on did not expect: say so rather than hang
            self._post("error", f"unexpected reply from the coordinator: {e!r}")
        finally:
            self._post("finished")

    def _submit_all(self):
        shas = {}
        jobs = {}
        for frame in self.exported:
            if self._cancel.is_set():
                break
            for name in frame.files:
                if name not in shas:
                    shas[name] = self.farm.upload(os.path.join(self.folder, name))
            with open(os.path.join(self.folder, frame.scene_file), encoding="utf-8") as f:
                text = f.read()
            body = {
                "scene": text,
                "scene_name": frame.scene_file,
                "spp": self.spp,
                "files": {name: shas[name] for name in frame.files},
            }
            try:
                reply = self.farm.submit(body)
            except FarmError as e:
                raise FarmError(f"frame {frame.number}: {e}") from None
            jobs[frame.number] = reply["job_id"]
            self._post("submitted", frame.number, reply["job_id"])
        return jobs

    def _status(self, job_id, since):
        """The job's status; `None` while the coordinator cannot be reached (for up to
        UNREACHABLE_S from `since`, the first failure), as while it restarts."""
        try:
            return self.farm.status(job_id)
        except FarmError as e:
            if not str(e).startswith("cannot reach") or time.monotonic() - since > UNREACHABLE_S:
                raise
            return None

    def _watch(self, jobs):
        running = dict(jobs)
        lost = None
        while running:
            if self._cancel.is_set():
                for job_id in running.values():
                    self.farm.cancel(job_id)
                self._post("error", "cancelled")
                return
            for number, job_id in list(running.items()):
                status = self._status(job_id, lost or time.monotonic())
                if status is None:
                    lost = lost or time.monotonic()
                    self._post("progress", number, "coordinator unreachable, retrying", None, None)
                    break
                lost = None
                self._post("progress", number, status["state"], status["units_done"], status["units_total"])
                if status["state"] == "done":
                    path = os.path.join(self.output_dir, f"{self.stem}.{number:04d}.exr")
                    data = self.farm.output(job_id)
                    os.makedirs(self.output_dir, exist_ok=True)
                    with open(path + ".part", "wb") as f:
                        f.write(data)
                    os.replace(path + ".part", path)
                    self._post("saved", number, path)
                    del running[number]
                elif status["state"] in ("failed", "cancelled"):
                    self._post("failed", number, status["error"] or status["state"])
                    del running[number]
            if running:
                time.sleep(POLL_S)

    # The main thread's side.

    def apply_events(self, on_saved):
        """Applies what the thread posted; calls `on_saved(path)` for each finished EXR."""
        by_number = {f.number: f for f in self.frames}
        changed = False
        while True:
            try:
                event = self.events.get_nowait()
            except queue.Empty:
                return changed
            changed = True
            kind, args = event[0], event[1:]
            if kind == "submitted":
                by_number[args[0]].job_id = args[1]
                by_number[args[0]].state = "queued"
            elif kind == "progress":
                f = by_number[args[0]]
                f.state = args[1]
                if args[2] is not None:
                    f.units_done, f.units_total = args[2], args[3]
            elif kind == "saved":
                by_number[args[0]].path = args[1]
                on_saved(args[1])
            elif kind == "failed":
                by_number[args[0]].state = "failed"
                by_number[args[0]].error = args[1]
            elif kind == "error":
                self.error = args[0]
            elif kind == "finished":
                self.finished = True

    def wait(self, timeout=None):
        """Waits for the thread (for scripts and tests; the UI never waits)."""
        self._thread.join(timeout)
        return not self._thread.is_alive()
