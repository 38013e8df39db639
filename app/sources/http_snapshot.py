"""The "http" source: GET a snapshot URL that answers with one JPEG/PNG (IP cameras, webcam servers)."""

from __future__ import annotations

import httpx
import numpy as np

from app.sources.base import ImageSource, SourceError, decode_bytes


def _url_without_password(url: str) -> str:
    """The URL as shown in messages: user info (``user:pass@``) removed."""
    try:
        parsed = httpx.URL(url)
    except Exception:
        return url
    return str(parsed.copy_with(username=None, password=None)) if parsed.userinfo else url


class HttpSnapshotSource(ImageSource):
    """One GET per grab; redirects followed; the body must decode as an image.

    For MJPEG/RTSP streams use the opencv source instead: a stream never ends, so it is refused here
    once it exceeds ``max_mb``.
    """

    kind = "http"

    def __init__(
        self,
        url: str,
        timeout_s: float = 5.0,
        username: str | None = None,
        password: str | None = None,
        auth: str = "basic",
        verify_tls: bool = True,
        max_mb: float = 50.0,
    ) -> None:
        self.url = url
        self.timeout_s = timeout_s
        self.verify_tls = verify_tls
        self.max_mb = max_mb
        self.max_bytes = int(max_mb * 1024 * 1024)
        self._auth: httpx.Auth | None = None
        if username is not None:
            pw = password or ""
            self._auth = httpx.DigestAuth(username, pw) if auth == "digest" else httpx.BasicAuth(username, pw)

    def describe(self) -> str:
        return f"HTTP snapshot {_url_without_password(self.url)}"

    def _fail(self, why: str) -> SourceError:
        return SourceError(f"{self.describe()}: {why}")

    def grab(self) -> np.ndarray:
        try:
            with httpx.Client(timeout=self.timeout_s, follow_redirects=True, verify=self.verify_tls,
                              auth=self._auth) as client:
                with client.stream("GET", self.url) as resp:
                    if resp.status_code != 200:
                        hint = "; check username and password" if resp.status_code in (401, 403) else ""
                        raise self._fail(f"server answered {resp.status_code} {resp.reason_phrase}{hint}")
                    content_type = resp.headers.get("content-type", "unknown")
                    chunks, size = [], 0
                    for chunk in resp.iter_bytes():
                        size += len(chunk)
                        if size > self.max_bytes:
                            raise self._fail(
                                f"answer exceeds {self.max_mb:g} MB (content-type {content_type}); "
                                "this looks like a video stream: use an opencv source for streams"
                            )
                        chunks.append(chunk)
        except httpx.ConnectError as exc:
            text = str(exc) or type(exc).__name__
            if "refused" in text.lower():
                raise self._fail("connection refused; check that the camera is on and the host and port "
                                 "are right") from None
            raise self._fail(f"cannot connect ({text})") from None
        except httpx.TimeoutException:
            raise self._fail(f"no answer within {self.timeout_s:g} s") from None
        except httpx.HTTPError as exc:
            raise self._fail(f"request failed ({type(exc).__name__}: {exc})") from None
        data = b"".join(chunks)
        image = decode_bytes(data)
        if image is None:
            raise self._fail(f"answer is not an image (content-type {content_type}, {len(data)} bytes)")
        return image
