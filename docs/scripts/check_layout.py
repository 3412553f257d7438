"""Check the built documentation site's layout in a real browser, and screenshot it.

    python docs/scripts/check_layout.py SITE_DIR SCREENSHOT_DIR [--width 1280]

Every page of the built site (`SITE_DIR`, e.g. `site/`) is opened in headless Chromium at
`--width` px (1280 by default) and searched for:

- tables and code blocks whose content is wider than their visible box (cut off, or
  needing a horizontal scroll bar to be read);
- any other box whose text is cut or scrolls sideways (an ellipsis, a clipped cell, a
  sidebar entry);
- anything sticking out of the content column or past the window's right edge.

One line is printed per offender (page, element, its content and visible widths, the
start of its text); the exit status is 1 when there is any, 0 when there is none. A
full-page screenshot of every page is saved as PNG into `SCREENSHOT_DIR`.

The browser is driven through the DevTools protocol over a pipe (`--remote-debugging-pipe`),
with the standard library only: one browser for all the pages. The site is served from
127.0.0.1 and every other host is unreachable for the browser (no web fonts: the theme's
fallback fonts, which are wider than Roboto, so a page that fits here fits with Roboto).
The browser is `--chromium`, `$CHROMIUM`, or the first of chromium, chromium-browser,
google-chrome found on the PATH. When there is none: with `--install-browser`, Chromium is
installed with `apt-get install -y chromium` where that can work (root, apt-get present);
then, still none, the exit status is 2, or 0 with `--skip-without-browser` (`make test`:
the check is reported as not done, and does not fail the build).
"""

from __future__ import annotations

import argparse
import functools
import http.server
import json
import os
import queue
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")

# Run in the page once it has loaded and its fonts are ready; returns the offenders.
MEASURE = r"""
(() => {
  const found = [];
  const vw = document.documentElement.clientWidth;
  const text = (el) => (el.innerText || el.textContent || "").trim().replace(/\s+/g, " ");
  const name = (el) => {
    let s = el.tagName.toLowerCase();
    if (el.id) s += "#" + el.id;
    const cls = [...el.classList].filter((c) => !c.startsWith("__")).slice(0, 2);
    if (cls.length) s += "." + cls.join(".");
    return s;
  };
  const heading = (h) => "under \"" + text(h).replace(/¶$/, "").trim().slice(0, 50) + "\"";
  const where = (el) => {
    const h = [];
    for (let p = el; p && p !== document.body; p = p.parentElement) {
      if (p.matches(".md-sidebar--primary")) return "navigation";
      if (p.matches(".md-sidebar--secondary")) return "table of contents";
      if (p.matches(".md-header")) return "header";
      if (p.matches(".md-footer")) return "footer";
    }
    // the heading this element comes under, for the reader to find it
    let node = el;
    while (node && node !== document.body) {
      let sib = node.previousElementSibling;
      while (sib) {
        if (/^H[1-6]$/.test(sib.tagName)) return heading(sib);
        const inner = sib.querySelectorAll("h1,h2,h3,h4,h5,h6");
        if (inner.length) return heading(inner[inner.length - 1]);
        sib = sib.previousElementSibling;
      }
      node = node.parentElement;
    }
    return "top of the page";
  };
  const kind = (el) => {
    if (el.closest("pre") || el.querySelector(":scope > pre, :scope > code")) return "code block";
    if (el.matches("table") || el.querySelector("table") || el.closest("table")) return "table";
    if (el.closest(".jp-OutputArea, .jp-Cell-outputWrapper")) return "notebook output";
    return "text";
  };
  // seen on the page: not hidden, transparent, or inside a closed <details>
  const shown = (el) => el.getClientRects().length > 0 && el.checkVisibility({
    contentVisibilityAuto: true, opacityProperty: true, visibilityProperty: true});
  const clipped = [];
  for (const el of document.querySelectorAll("body *")) {
    const cs = getComputedStyle(el);
    if (cs.overflowX === "visible") continue;
    if (el.scrollWidth <= el.clientWidth + 1) continue;
    if (!shown(el)) continue;
    if (el.closest(".md-search, .md-dialog, .md-tooltip, .md-clipboard, .md-code__nav")) continue;
    clipped.push(el);
  }
  for (const el of clipped) {
    // the innermost box only: a box that clips because of another reported box inside it
    if (clipped.some((o) => o !== el && el.contains(o))) continue;
    const cs = getComputedStyle(el);
    const how = cs.textOverflow === "ellipsis" ? "cut with an ellipsis"
      : (cs.overflowX === "hidden" || cs.overflowX === "clip") ? "cut" : "scrolls sideways";
    found.push({kind: kind(el), how, element: name(el), where: where(el),
                content: el.scrollWidth, visible: el.clientWidth, text: text(el).slice(0, 70)});
  }
  // boxes that stick out of the content column (over the table of contents) or the window;
  // the column's own margins are the theme's to use (a table's scroll box reaches into them)
  const column = document.querySelector(".md-content__inner");
  if (column) {
    const limit = Math.min(column.parentElement.getBoundingClientRect().right, vw);
    const out = [];
    for (const el of column.querySelectorAll("*")) {
      const r = el.getBoundingClientRect();
      if (r.width === 0 || r.right <= limit + 1) continue;
      // clipped by a box inside the column: already reported above, or not seen
      let clip = false;
      for (let p = el.parentElement; p && p !== column; p = p.parentElement) {
        if (getComputedStyle(p).overflowX !== "visible") { clip = true; break; }
      }
      if (clip || !shown(el)) continue;
      out.push(el);
    }
    for (const el of out) {
      if (out.some((o) => o !== el && o.contains(el))) continue;  // the outermost only
      const left = column.getBoundingClientRect().left;
      found.push({kind: kind(el), how: "sticks out of the content column", element: name(el),
                  where: where(el), content: Math.round(el.getBoundingClientRect().right - left),
                  visible: Math.round(limit - left), text: text(el).slice(0, 70)});
    }
  }
  if (document.documentElement.scrollWidth > vw + 1) {
    found.push({kind: "page", how: "wider than the window", element: "html", where: "",
                content: document.documentElement.scrollWidth, visible: vw, text: ""});
  }
  return {offenders: found, height: document.documentElement.scrollHeight};
})()
"""


class Browser:
    """Headless Chromium driven through the DevTools protocol over a pipe."""

    def __init__(self, executable: str, width: int, height: int, timeout: float = 120.0):
        self.width, self.height, self.timeout = width, height, timeout
        self._profile = tempfile.TemporaryDirectory(prefix="check_layout_")
        to_browser_r, self._to_browser = os.pipe()
        self._from_browser, from_browser_w = os.pipe()

        def child_fds() -> None:  # the browser reads fd 3 and writes fd 4
            a, b = os.dup(to_browser_r), os.dup(from_browser_w)
            os.dup2(a, 3)
            os.dup2(b, 4)

        args = [
            executable,
            "--headless=new",
            "--remote-debugging-pipe",
            "--disable-gpu",
            "--disable-dev-shm-usage",
            "--no-first-run",
            "--no-default-browser-check",
            "--disable-extensions",
            "--mute-audio",
            f"--user-data-dir={self._profile.name}",
            f"--window-size={width},{height}",
            # only the local server: no web fonts, no CDN scripts, nothing to wait for
            "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
        ]
        if hasattr(os, "geteuid") and os.geteuid() == 0:
            args.append("--no-sandbox")  # Chromium refuses to run as root with its sandbox
        self._proc = subprocess.Popen(
            args,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            preexec_fn=child_fds,
            close_fds=False,
        )
        os.close(to_browser_r)
        os.close(from_browser_w)
        self._next_id = 0
        self._replies: dict[int, dict] = {}
        self._events: queue.Queue[dict] = queue.Queue()
        self._cond = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self._session = self.call("Target.attachToTarget", targetId=target, flatten=True)[
            "sessionId"
        ]
        self.call("Page.enable", session=True)
        self.call(
            "Emulation.setDeviceMetricsOverride",
            session=True,
            width=width,
            height=height,
            deviceScaleFactor=1,
            mobile=False,
        )

    def _read(self) -> None:
        buffer = b""
        with os.fdopen(self._from_browser, "rb", buffering=0) as pipe:
            while chunk := pipe.read(1 << 16):
                buffer += chunk
                *messages, buffer = buffer.split(b"\0")
                for raw in messages:
                    message = json.loads(raw)
                    if "id" in message:
                        with self._cond:
                            self._replies[message["id"]] = message
                            self._cond.notify_all()
                    else:
                        self._events.put(message)
        with self._cond:
            self._replies[-1] = {}
            self._cond.notify_all()

    def call(self, method: str, session: bool = False, **params) -> dict:
        self._next_id += 1
        ident = self._next_id
        message = {"id": ident, "method": method, "params": params}
        if session:
            message["sessionId"] = self._session
        os.write(self._to_browser, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        with self._cond:
            while ident not in self._replies:
                if -1 in self._replies:
                    raise RuntimeError(f"the browser exited during {method}")
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"{method}: no answer in {self.timeout:g} s")
                self._cond.wait(left)
            reply = self._replies.pop(ident)
        if "error" in reply:
            raise RuntimeError(f"{method}: {reply['error'].get('message')}")
        return reply.get("result", {})

    def open(self, url: str) -> None:
        """Load `url` and wait for its load event and its fonts."""
        while not self._events.empty():
            self._events.get_nowait()
        self.call("Page.navigate", session=True, url=url)
        deadline = time.monotonic() + self.timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"{url}: not loaded in {self.timeout:g} s")
            try:
                event = self._events.get(timeout=left)
            except queue.Empty:
                continue
            if event.get("method") == "Page.loadEventFired":
                break
        # the theme's scripts run on load; give them and the fonts a moment
        self.evaluate(
            "document.fonts.ready.then(() => new Promise((r) => setTimeout(r, 150)))",
            await_promise=True,
        )

    def evaluate(self, expression: str, await_promise: bool = False):
        result = self.call(
            "Runtime.evaluate",
            session=True,
            expression=expression,
            returnByValue=True,
            awaitPromise=await_promise,
        )
        if "exceptionDetails" in result:
            raise RuntimeError(f"script failed: {result['exceptionDetails'].get('text')}")
        return result["result"].get("value")

    def screenshot(self, path: Path, height: int) -> None:
        """A PNG of the whole page, `height` px tall (at most 16,384 px)."""
        import base64

        height = max(self.height, min(height, 16384))
        data = self.call(
            "Page.captureScreenshot",
            session=True,
            format="png",
            captureBeyondViewport=True,
            clip={"x": 0, "y": 0, "width": self.width, "height": height, "scale": 1},
        )["data"]
        path.write_bytes(base64.b64decode(data))

    def close(self) -> None:
        try:
            self.call("Browser.close")
        except (RuntimeError, TimeoutError, OSError):
            pass
        try:
            self._proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        os.close(self._to_browser)
        self._profile.cleanup()


def find_browser(given: str | None) -> str | None:
    for candidate in (given, os.environ.get("CHROMIUM"), *BROWSERS):
        if candidate and (found := shutil.which(candidate)):
            return found
    return None


def install_browser() -> str | None:
    """`apt-get install -y chromium` (after `apt-get update` if that alone fails), where
    this process is root and has apt-get; the browser found afterwards, or None."""
    if not hasattr(os, "geteuid") or os.geteuid() != 0 or shutil.which("apt-get") is None:
        print("check_layout: cannot install Chromium here (needs root and apt-get)")
        return None
    print("check_layout: no Chromium; installing it: apt-get install -y chromium", flush=True)
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    install = ["apt-get", "install", "-y", "-q", "chromium"]
    for commands in ([install], [["apt-get", "update", "-q"], install]):
        log = ""
        for command in commands:
            done = subprocess.run(command, env=env, capture_output=True, text=True)
            log += done.stdout + done.stderr
            if done.returncode != 0:
                break
        else:
            return find_browser(None)
    print("check_layout: apt-get could not install Chromium:\n" + log.strip()[-2000:])
    return None


def pages(site: Path) -> list[Path]:
    """Every HTML page of the site (not the theme's assets or the search index)."""
    skip = {"assets", "search"}
    return sorted(
        p.relative_to(site)
        for p in site.rglob("*.html")
        if not skip.intersection(p.relative_to(site).parts[:1])
    )


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: object) -> None:  # noqa: A002
        pass


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("site", type=Path, help="the built site (mkdocs build --site-dir)")
    parser.add_argument("screenshots", type=Path, help="folder for one PNG per page")
    parser.add_argument("--width", type=int, default=1280, help="window width, px")
    parser.add_argument("--height", type=int, default=900, help="window height, px")
    parser.add_argument("--chromium", help="the browser to run (default: found on PATH)")
    parser.add_argument("--page", action="append", help="check only these pages (repeatable)")
    parser.add_argument(
        "--install-browser",
        action="store_true",
        help="without a browser, install Chromium with apt-get (root only)",
    )
    parser.add_argument(
        "--skip-without-browser",
        action="store_true",
        help="without a browser, say the check was not done and exit 0",
    )
    args = parser.parse_args(argv)

    browser_path = find_browser(args.chromium)
    if browser_path is None and args.install_browser:
        browser_path = install_browser()
    if browser_path is None:
        print(
            "check_layout: NOT CHECKED: no Chromium (" + ", ".join(BROWSERS) + ") on the PATH; "
            "install it (Debian/Ubuntu: apt-get install chromium) to check the pages' layout",
            file=sys.stderr,
        )
        return 0 if args.skip_without_browser else 2
    site = args.site.resolve()
    if not (site / "index.html").is_file():
        print(f"check_layout: {site} has no index.html: build the site first", file=sys.stderr)
        return 2
    args.screenshots.mkdir(parents=True, exist_ok=True)
    todo = [Path(p) for p in args.page] if args.page else pages(site)

    start = time.monotonic()
    server = http.server.ThreadingHTTPServer(
        ("127.0.0.1", 0), functools.partial(_Quiet, directory=str(site))
    )
    browser = Browser(browser_path, args.width, args.height)  # before the server's thread
    threading.Thread(target=server.serve_forever, daemon=True).start()
    base = f"http://127.0.0.1:{server.server_address[1]}/"
    offenders = 0
    try:
        for page in todo:
            browser.open(base + page.as_posix())
            found = browser.evaluate(MEASURE)
            shot = args.screenshots / (page.with_suffix("").as_posix().replace("/", "__") + ".png")
            browser.screenshot(shot, found["height"])
            for o in found["offenders"]:
                offenders += 1
                where = f" ({o['where']})" if o["where"] else ""
                snippet = f': "{o["text"]}"' if o["text"] else ""
                print(
                    f"{page.as_posix()}: {o['kind']} {o['how']}{where}: {o['element']}, "
                    f"content {o['content']} px in {o['visible']} px{snippet}"
                )
    finally:
        browser.close()
        server.shutdown()
        server.server_close()
    print(
        f"check_layout: {len(todo)} pages at {args.width} px, {offenders} offenders, "
        f"{time.monotonic() - start:.0f} s (Chromium: {browser_path}; "
        f"screenshots in {args.screenshots})"
    )
    return 1 if offenders else 0


if __name__ == "__main__":
    sys.exit(main())
