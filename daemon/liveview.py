"""The live view: a small read-only web page of what the daemon sees.

Mounting a stereo camera is done by looking. With ``liveview.enabled: true`` the
daemon serves, on ``liveview.host:liveview.port`` (loopback unless configured):

- ``/``: one HTML page (no framework, a few lines of script) showing the rectified
  left image and the disparity side by side with a colour bar (disparity px and the
  distance it means), the ranging region (yellow) and the object's box (green),
  the distance measured, quality, age, fps and what is on the wire;
- ``/frame.jpg``: that picture as one JPEG;
- ``/state.json``: the figures.

Cost: the stereo loop only hands over references to arrays it made anyway
(:meth:`LiveView.offer`, one assignment); nothing is drawn or encoded unless a
client asks for ``/frame.jpg``, and then at most ``liveview.max_fps`` times a
second by one encoder (others get the cached JPEG). The server runs on daemon
threads of its own and never touches the send clock.
"""

from __future__ import annotations

import http.server
import json
import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from uav_depth.core.errors import ConfigError
from uav_depth.core.keys import Key
from uav_depth.core.params import StereoParams

log = logging.getLogger("uav_depth.liveview")


def _check_host(value: Any) -> str | None:
    return None if isinstance(value, str) and value and " " not in value else "must be a host name or IP address"


@dataclass(frozen=True)
class LiveViewConfig:
    """The ``liveview:`` section of the run config."""

    enabled: bool = False
    host: str = "127.0.0.1"
    port: int = 8765
    max_fps: float = 5.0
    panel_width_px: int = 480

    KEYS = (
        Key("enabled", "bool", False, "serve the read-only live view web page (left image, disparity, region, "
            "distance, wire state); off: nothing is served and nothing is drawn"),
        Key("host", "str", "127.0.0.1", "address the live view listens on; 127.0.0.1 keeps it on the drone "
            "(reach it over ssh -L), 0.0.0.0 opens it to every network the drone is on", check=_check_host),
        Key("port", "int", 8765, "TCP port of the live view", 1, 65535),
        Key("max_fps", "float", 5.0, "most pictures drawn and JPEG-encoded per second, whatever the number of "
            "viewers (bounds the CPU the view takes from the flight loop)", 0.2, 15.0),
        Key("panel_width_px", "int", 480, "width of each of the two panels in the picture, px", 160, 1920),
    )


@dataclass(frozen=True)
class Offer:
    """What the stereo loop hands over per frame: references, never copies.

    ``left``: (H, W[, 3]) uint8 rectified left image; ``disparity``: (H, W) float32 px,
    NaN where invalid; ``estimate``: the frame's :class:`~uav_depth.daemon.estimate.Estimate`;
    ``roi``: the ranging region (x0, y0, x1, y1) px; ``params``: the StereoParams that
    computed it (their search range is the colour scale).
    """

    left: np.ndarray
    disparity: np.ndarray
    estimate: Any
    roi: tuple[int, int, int, int]
    params: StereoParams

    @property
    def disparity_range(self) -> tuple[float, float]:
        """(lo, hi) px in input pixels: the parameters' search range (matched px / compute.scale)."""
        sg, scale = self.params.sgbm, self.params.compute.scale
        return sg.min_disparity / scale, (sg.min_disparity + sg.num_disparities) / scale


def wire_fields(report: Any) -> dict[str, Any]:
    """The last DISTANCE_SENSOR decision of the send clock, as the page shows it.

    ``sent``: a message went out (False in every blind condition, and before the first);
    ``condition``: the clock's name for the case (measuring, too close, stale, ...);
    ``valid``: a measured distance.
    """
    if report is None:
        return {"sent": False, "condition": "nothing yet", "valid": False}
    current = getattr(report, "current_distance", None)
    out: dict[str, Any] = {"sent": current is not None, "condition": str(getattr(report, "condition", "")),
                           "valid": bool(getattr(report, "valid", False))}
    if current is not None:
        for name in ("current_distance", "min_distance", "max_distance", "signal_quality", "covariance"):
            v = getattr(report, name, None)
            out[name] = None if v is None else int(v)
    return out


class LiveView:
    """The live view server. ``start()`` binds and serves; ``close()`` stops it.

    ``fb_px_m``: focal length x baseline (px m) of the rectified pair, for the colour
    bar's distances; ``status``: returns a mapping with the daemon's ``state``,
    ``fps`` and the last DISTANCE_SENSOR sent (``wire``, see :func:`wire_fields`).
    """

    def __init__(self, config: LiveViewConfig, fb_px_m: float, status: Callable[[], dict[str, Any]],
                 clock: Callable[[], float] = time.monotonic):
        self.config = config
        self.fb_px_m = fb_px_m
        self.status = status
        self.clock = clock
        self._offer: Offer | None = None      # replaced by one assignment per frame
        self._encode_lock = threading.Lock()
        self._jpeg: bytes | None = None
        self._jpeg_t = -math.inf
        self._jpeg_frame = -1
        self.encoded = 0                      # pictures drawn and encoded so far
        self.last_request: float | None = None
        self._server: http.server.ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None

    # -- the stereo loop's side: one assignment -------------------------------------------------
    def offer(self, left: np.ndarray, disparity: np.ndarray, estimate: Any, roi: tuple[int, int, int, int],
              params: StereoParams) -> None:
        self._offer = Offer(left, disparity, estimate, roi, params)

    # -- server ---------------------------------------------------------------------------------
    @property
    def address(self) -> tuple[str, int]:
        assert self._server is not None
        host, port = self._server.server_address[:2]
        return str(host), int(port)

    @property
    def url(self) -> str:
        host, port = self.address
        return f"http://{host}:{port}/"

    def start(self) -> "LiveView":
        """Bind and serve on a daemon thread. OSError when the address is taken."""
        view = self

        class Handler(_Handler):
            liveview = view

        server = http.server.ThreadingHTTPServer((self.config.host, self.config.port), Handler)
        server.daemon_threads = True
        self._server = server
        self._thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.2},
                                        name="liveview", daemon=True)
        self._thread.start()
        log.info("live view on %s (read-only; at most %g pictures/s)", self.url, self.config.max_fps)
        return self

    @property
    def alive(self) -> bool:
        """The server thread runs."""
        return self._thread is not None and self._thread.is_alive()

    @classmethod
    def bind(cls, config: LiveViewConfig, fb_px_m: float, status: Callable[[], dict[str, Any]]) -> "LiveView":
        """Build and start one; ConfigError naming ``liveview.port`` when the address cannot be bound."""
        try:
            return cls(config, fb_px_m, status).start()
        except OSError as exc:
            raise ConfigError("liveview.port", f"must be free to listen on at {config.host} ({exc.strerror})",
                              config.port) from exc

    def close(self, timeout_s: float = 1.0) -> bool:
        """Stop serving; True when the server thread ended within ``timeout_s``."""
        if self._server is None:
            return True
        done = threading.Thread(target=self._server.shutdown, daemon=True)
        done.start()
        done.join(timeout_s)
        self._server.server_close()
        if self._thread is not None:
            self._thread.join(max(0.0, timeout_s))
            return not self._thread.is_alive()
        return True

    # -- what the page reads --------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        """The figures of ``/state.json``."""
        now = self.clock()
        st = dict(self.status())
        st["wire"] = wire_fields(st.get("wire"))
        offer = self._offer
        if offer is None:
            st["frame"] = None
            return st
        est = offer.estimate
        m = est.measurement
        st["frame"] = {
            "index": int(est.frame_index),
            "age_ms": round((now - est.t_capture) * 1000.0, 1),
            "latency_ms": round(float(est.timings_ms.get("latency", math.nan)), 1),
            "distance_m": None if m.distance_m is None else round(float(m.distance_m), 4),
            "quality": int(m.quality),
            "reason": m.reason,
            "truth_m": None if est.truth_m is None else round(float(est.truth_m), 4),
            "bbox": list(m.bbox) if m.bbox else None,
            "roi": list(offer.roi),
            "params_hash": est.params_hash[:8],
        }
        return st

    def jpeg(self) -> bytes | None:
        """The picture of the newest frame; drawn at most ``max_fps`` times a second, by one caller at a time."""
        with self._encode_lock:
            offer = self._offer
            now = self.clock()
            if offer is None:
                return None
            fresh = now - self._jpeg_t < 1.0 / self.config.max_fps
            if self._jpeg is not None and (fresh or offer.estimate.frame_index == self._jpeg_frame):
                return self._jpeg
            import cv2

            picture = render(offer, self.config.panel_width_px, self.fb_px_m)
            ok, buf = cv2.imencode(".jpg", picture, [cv2.IMWRITE_JPEG_QUALITY, 80])
            if not ok:
                return self._jpeg
            self._jpeg, self._jpeg_t, self._jpeg_frame = buf.tobytes(), now, offer.estimate.frame_index
            self.encoded += 1
            return self._jpeg


# -- drawing (pure) -------------------------------------------------------------------------------

_YELLOW, _GREEN, _WHITE = (0, 220, 255), (60, 230, 60), (255, 255, 255)


def colourise(disparity: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(H, W) float disparity -> (H, W, 3) uint8 BGR, TURBO from ``lo`` (far, blue) to ``hi`` (near, red); NaN black."""
    import cv2

    span = max(hi - lo, 1e-6)
    valid = np.isfinite(disparity)
    scaled = np.zeros(disparity.shape, np.uint8)
    scaled[valid] = np.clip((disparity[valid] - lo) * (255.0 / span), 0, 255).astype(np.uint8)
    out = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)
    out[~valid] = 0
    return out


def colour_bar(width: int, lo: float, hi: float, fb_px_m: float) -> np.ndarray:
    """A (52, width, 3) colour bar with ticks: disparity px above, the distance f*B/d below."""
    import cv2

    ramp = np.linspace(0, 255, width).astype(np.uint8)[None, :].repeat(16, 0)
    bar = np.zeros((52, width, 3), np.uint8)
    bar[4:20] = cv2.applyColorMap(ramp, cv2.COLORMAP_TURBO)
    for i in range(5):
        d = lo + (hi - lo) * i / 4
        x = int(round((width - 1) * i / 4))
        cv2.line(bar, (x, 20), (x, 25), _WHITE, 1)
        z = f"{fb_px_m / d:.2f} m" if d > 0 else "inf"
        tx = min(max(x - 18, 0), width - 48)
        cv2.putText(bar, f"{d:.0f} px", (tx, 36), cv2.FONT_HERSHEY_SIMPLEX, 0.35, _WHITE, 1, cv2.LINE_AA)
        cv2.putText(bar, z, (tx, 49), cv2.FONT_HERSHEY_SIMPLEX, 0.35, _WHITE, 1, cv2.LINE_AA)
    return bar


def render(offer: Offer, panel_width_px: int, fb_px_m: float) -> np.ndarray:
    """The picture: left | disparity, each ``panel_width_px`` wide, region and box drawn, colour bar below."""
    import cv2

    left = offer.left if offer.left.ndim == 3 else cv2.cvtColor(offer.left, cv2.COLOR_GRAY2BGR)
    h, w = left.shape[:2]
    s = panel_width_px / w
    ph = max(1, int(round(h * s)))
    lo, hi = offer.disparity_range
    panels = [cv2.resize(left, (panel_width_px, ph), interpolation=cv2.INTER_AREA),
              cv2.resize(colourise(offer.disparity, lo, hi), (panel_width_px, ph),
                         interpolation=cv2.INTER_NEAREST)]
    m = offer.estimate.measurement
    for p in panels:
        x0, y0, x1, y1 = offer.roi
        cv2.rectangle(p, (int(x0 * s), int(y0 * s)), (int(x1 * s) - 1, int(y1 * s) - 1), _YELLOW, 1)
        if m.bbox:
            bx0, by0, bx1, by1 = m.bbox
            cv2.rectangle(p, (int(bx0 * s), int(by0 * s)), (int(bx1 * s) - 1, int(by1 * s) - 1), _GREEN, 2)
    text = f"{m.distance_m:.3f} m  q {m.quality}" if m.distance_m is not None else f"no measurement: {m.reason}"
    (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.6, 1)
    cv2.rectangle(panels[0], (4, 4), (12 + tw, 12 + th), (0, 0, 0), -1)
    cv2.putText(panels[0], text, (8, 8 + th), cv2.FONT_HERSHEY_SIMPLEX, 0.6, _WHITE, 1, cv2.LINE_AA)
    top = np.hstack(panels)
    bottom = np.zeros((52, top.shape[1], 3), np.uint8)
    bottom[:, panel_width_px:] = colour_bar(panel_width_px, lo, hi, fb_px_m)
    cv2.putText(bottom, "yellow: ranging region  green: object", (8, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                _WHITE, 1, cv2.LINE_AA)
    return np.vstack([top, bottom])


# -- HTTP -----------------------------------------------------------------------------------------

class _Handler(http.server.BaseHTTPRequestHandler):
    liveview: LiveView
    server_version = "uav-depth-liveview"

    def log_message(self, fmt: str, *args: Any) -> None:   # journald gets no line per request
        log.debug("liveview %s: " + fmt, self.client_address[0], *args)

    def do_GET(self) -> None:   # noqa: N802 (http.server's name)
        view = self.liveview
        view.last_request = view.clock()
        path = self.path.split("?", 1)[0]
        if path == "/":
            self._reply(200, "text/html; charset=utf-8", page(view.config.max_fps).encode())
        elif path == "/state.json":
            self._reply(200, "application/json", json.dumps(view.state()).encode())
        elif path == "/frame.jpg":
            data = view.jpeg()
            if data is None:
                self._reply(503, "text/plain", b"no frame yet")
            else:
                self._reply(200, "image/jpeg", data)
        else:
            self._reply(404, "text/plain", b"not found")

    def do_POST(self) -> None:  # noqa: N802  read-only: nothing can be changed from the page
        self._reply(405, "text/plain", b"read-only")

    def _reply(self, code: int, ctype: str, body: bytes) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        try:
            self.wfile.write(body)
        except (BrokenPipeError, ConnectionResetError):   # the viewer went away mid-reply
            pass


def page(max_fps: float) -> str:
    """The HTML page: the picture, reloaded at ``max_fps``, and the figures, polled from /state.json."""
    period_ms = int(round(1000.0 / max_fps))
    return f"""<!doctype html>
<html><head><meta charset="utf-8"><title>uav-depth live view</title>
<style>
body {{ font-family: sans-serif; background: #111; color: #eee; margin: 12px; }}
table {{ border-collapse: collapse; margin-top: 8px; }}
td {{ padding: 2px 12px 2px 0; }} td.k {{ color: #9ab; }}
.bad {{ color: #f66; }} .ok {{ color: #6f6; }}
</style></head>
<body>
<h3>uav-depth live view <span id="state">-</span></h3>
<img id="frame" alt="waiting for the first frame" src="/frame.jpg">
<table>
<tr><td class="k">measured</td><td><span id="distance-m">-</span> m
  (quality <span id="quality">-</span>, truth <span id="truth-m">-</span>)</td></tr>
<tr><td class="k">on the wire</td><td id="wire"><span id="wire-distance-cm">-</span> cm,
  quality <span id="wire-quality">-</span>, <span id="wire-valid">-</span></td></tr>
<tr><td class="k">age</td><td><span id="age-ms">-</span> ms (latency <span id="latency-ms">-</span> ms)</td></tr>
<tr><td class="k">stereo rate</td><td><span id="fps">-</span> fps</td></tr>
<tr><td class="k">frame</td><td><span id="frame-index">-</span>, params <span id="params">-</span></td></tr>
</table>
<script>
function set(id, v) {{ document.getElementById(id).textContent = (v === null || v === undefined) ? "-" : v; }}
function poll() {{
  fetch("/state.json", {{cache: "no-store"}}).then(r => r.json()).then(s => {{
    set("state", s.state); set("fps", s.fps.toFixed(1));
    const w = s.wire;
    if (w.sent) {{
      set("wire-distance-cm", w.current_distance); set("wire-quality", w.signal_quality);
      set("wire-valid", w.valid ? "a measurement" : w.condition);
    }} else {{
      set("wire-distance-cm", "-"); set("wire-quality", "-");
      set("wire-valid", "nothing sent (" + w.condition + ")");
    }}
    document.getElementById("wire").className = w.valid ? "ok" : "bad";
    const f = s.frame;
    if (f) {{
      set("distance-m", f.distance_m === null ? "none (" + f.reason + ")" : f.distance_m.toFixed(3));
      set("quality", f.quality); set("truth-m", f.truth_m === null ? "-" : f.truth_m.toFixed(3));
      set("age-ms", f.age_ms.toFixed(0)); set("latency-ms", f.latency_ms.toFixed(0));
      set("frame-index", f.index); set("params", f.params_hash);
    }}
    document.body.dataset.polled = String(Number(document.body.dataset.polled || 0) + 1);
  }}).catch(() => set("state", "(daemon unreachable)")).finally(() => setTimeout(poll, 200));
}}
const img = document.getElementById("frame");
img.onload = img.onerror = () => setTimeout(() => {{ img.src = "/frame.jpg?t=" + Date.now(); }}, {period_ms});
poll();
</script>
</body></html>
"""
