"""The coordinator's HTTP API (docs/farm.md, "The HTTP API for pipelines"), with nothing but
Python's standard library, so that the add-on needs no packages Blender lacks.

Every failure is a `FarmError` whose text is what an artist can act on: the coordinator's own
message for a refused request (`invalid_argument: scene.0001.toml:3:9: …`), or what went wrong
reaching it (`cannot reach the coordinator at http://…: connection refused`).
"""

import hashlib
import json
import socket
import urllib.error
import urllib.parse
import urllib.request

# Long enough for a slow coordinator, short enough that a dead address is noticed.
TIMEOUT_S = 30
# Uploads go in pieces the coordinator stores one at a time, so that a dropped connection
# resumes where it stopped (`GET /api/assets/SHA` says where) instead of starting again.
UPLOAD_PIECE = 16 << 20


class FarmError(Exception):
    """A request the coordinator refused, or could not be asked; `str()` is the message."""


class Farm:
    """One coordinator's HTTP API at `url` (e.g. `http://farm:7880`), with an optional token."""

    def __init__(self, url, token=""):
        url = url.strip().rstrip("/")
        if not url:
            raise FarmError("no coordinator address: set it in the tessera add-on's preferences")
        if "://" not in url:
            url = "http://" + url
        parts = urllib.parse.urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.netloc:
            raise FarmError(f"the coordinator address {url!r} is not an http:// or https:// URL")
        self.url = url
        self.token = token.strip()

    def call(self, method, path, body=None, data=None):
        """One request; JSON replies are decoded, others returned as bytes."""
        headers = {"Authorization": f"Bearer {self.token}"} if self.token else {}
        if body is not None:
            data, headers["Content-Type"] = json.dumps(body).encode(), "application/json"
        request = urllib.request.Request(self.url + path, data=data, method=method, headers=headers)
        try:
            with urllib.request.urlopen(request, timeout=TIMEOUT_S) as reply:
                raw = reply.read()
                if reply.headers.get_content_type() == "application/json":
                    return json.loads(raw)
                return raw
        except urllib.error.HTTPError as e:
            raise FarmError(_refusal(e)) from None
        except (urllib.error.URLError, socket.timeout, ConnectionError) as e:
            reason = getattr(e, "reason", e)
            # "[Errno 111] Connection refused" reads better as "connection refused".
            text = getattr(reason, "strerror", None) or str(reason)
            raise FarmError(f"cannot reach the coordinator at {self.url}: {text.lower()}") from None

    def upload(self, path):
        """Sends the file at `path` unless the coordinator holds its content; its SHA-256."""
        with open(path, "rb") as f:
            data = f.read()
        sha = hashlib.sha256(data).hexdigest()
        held = self.call("GET", f"/api/assets/{sha}")
        at = held.get("received", 0) if not held.get("complete") else len(data)
        while at < len(data):
            piece = data[at : at + UPLOAD_PIECE]
            reply = self.call("PUT", f"/api/assets/{sha}?offset={at}&total={len(data)}", data=piece)
            at = reply.get("received", at + len(piece)) if isinstance(reply, dict) else at + len(piece)
        return sha

    def submit(self, body):
        """Submits a job (`POST /api/jobs`); the coordinator's reply (`job_id`, …)."""
        return self.call("POST", "/api/jobs", body)

    def status(self, job_id):
        """The job's status (`GET /api/jobs/JOB`)."""
        return self.call("GET", f"/api/jobs/{urllib.parse.quote(job_id)}")

    def cancel(self, job_id):
        """Cancels the job."""
        return self.call("POST", f"/api/jobs/{urllib.parse.quote(job_id)}/cancel")

    def output(self, job_id):
        """The finished job's EXR, byte for byte the coordinator's file."""
        return self.call("GET", f"/api/jobs/{urllib.parse.quote(job_id)}/output.exr")


def _refusal(e):
    """The coordinator's `{"code", "error"}` as one line, or the HTTP status when it sent none."""
    raw = e.read()
    try:
        reply = json.loads(raw)
        return f"{reply['code']}: {reply['error']}"
    except (ValueError, KeyError, TypeError):
        text = raw.decode("utf-8", "replace").strip()[:300]
        return f"HTTP {e.code} {e.reason}" + (f": {text}" if text else "")
