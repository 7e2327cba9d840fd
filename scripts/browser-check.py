#!/usr/bin/env python3
"""Open a report page in headless Chromium (Debian's `chromium`) and say what a person's browser did with it.

    browser-check.py PAGE.html SCREENSHOT.png [--width 1280] [--height 900]

Drives Chromium over the DevTools protocol on a pipe (--remote-debugging-pipe: fd 3 in, fd 4 out, one JSON
message per NUL), Python's standard library only. Prints one JSON object on stdout:

  images          each <img>: its src's scheme, natural width and whether it completed
  console_errors  console.error calls, uncaught exceptions, and error log entries (CSP violations among them)
  requests        every URL the page asked for (the page itself included)
  dialogs         alert/confirm/prompt dialogs the page opened (a script ran)
  gates           the #gates table: [gate, value text] per row
  title           the <h1 id="title"> text
  scripts         <script> elements; handlers: elements with an on* attribute
  screenshot      the full-page PNG written

Exit 2 when Chromium is missing (install: apt-get install chromium), 3 when it does not answer in time.
"""
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

EVAL = r"""
JSON.stringify({
  images: [...document.images].map(i => ({src: i.src.slice(0, 22), natural_width: i.naturalWidth, complete: i.complete})),
  gates: [...document.querySelectorAll('#gates tbody tr')].map(r => [...r.cells].slice(0, 2).map(c => c.textContent)),
  title: (document.getElementById('title') || {}).textContent,
  scripts: document.scripts.length,
  handlers: [...document.querySelectorAll('*')].filter(e => [...e.attributes].some(a => a.name.startsWith('on'))).length,
  page_width: document.documentElement.scrollWidth,
})
"""


def main():
    args = sys.argv[1:]
    if len(args) < 2:
        sys.exit(__doc__)
    page, shot = os.path.abspath(args[0]), os.path.abspath(args[1])
    width = int(args[args.index("--width") + 1]) if "--width" in args else 1280
    height = int(args[args.index("--height") + 1]) if "--height" in args else 900
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if not exe:
        print("chromium is not installed: apt-get install chromium (scripts/setup-daemon-tests.sh does)", file=sys.stderr)
        sys.exit(2)
    profile = tempfile.mkdtemp(prefix="scanstation-chromium-")
    to_chrome_r, to_chrome_w = os.pipe()
    from_chrome_r, from_chrome_w = os.pipe()
    # Chromium reads fd 3 and writes fd 4.
    def child_fds():
        # dup2 clears close-on-exec on the new descriptors; nothing else of ours is inheritable.
        r, w = os.dup(to_chrome_r), os.dup(from_chrome_w)
        os.dup2(r, 3)
        os.dup2(w, 4)
    proc = subprocess.Popen(
        [exe, "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--remote-debugging-pipe",
         f"--user-data-dir={profile}", "--no-first-run", "--no-default-browser-check",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "about:blank"],
        close_fds=False, preexec_fn=child_fds,
        stdout=subprocess.DEVNULL, stderr=None if os.environ.get("BROWSER_CHECK_DEBUG") else subprocess.DEVNULL)
    os.close(to_chrome_r)
    os.close(from_chrome_w)
    out = os.fdopen(to_chrome_w, "wb", buffering=0)
    inp = os.fdopen(from_chrome_r, "rb", buffering=0)
    buf = bytearray()
    events = []
    next_id = [0]
    deadline = time.time() + 60

    def read_message():
        while b"\0" not in buf:
            if time.time() > deadline:
                raise TimeoutError
            chunk = inp.read(65536)
            if not chunk:
                raise EOFError("chromium closed the pipe")
            buf.extend(chunk)
        i = buf.index(b"\0")
        msg = json.loads(buf[:i].decode())
        del buf[:i + 1]
        return msg

    def call(method, params=None, session=None):
        next_id[0] += 1
        mid = next_id[0]
        msg = {"id": mid, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        out.write(json.dumps(msg).encode() + b"\0")
        while True:
            m = read_message()
            if m.get("id") == mid:
                if "error" in m:
                    raise RuntimeError(f"{method}: {m['error']}")
                return m.get("result", {})
            events.append(m)

    def wait_for(method):
        for e in events:
            if e.get("method") == method:
                return e
        while True:
            m = read_message()
            events.append(m)
            if m.get("method") == method:
                return m

    try:
        targets = call("Target.getTargets")["targetInfos"]
        target = next(t for t in targets if t["type"] == "page")
        session = call("Target.attachToTarget", {"targetId": target["targetId"], "flatten": True})["sessionId"]
        for domain in ("Runtime", "Log", "Network", "Page"):
            call(f"{domain}.enable", session=session)
        call("Emulation.setDeviceMetricsOverride",
             {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": width < 600}, session=session)
        call("Page.navigate", {"url": "file://" + page}, session=session)
        wait_for("Page.loadEventFired")
        found = json.loads(call("Runtime.evaluate", {"expression": EVAL, "returnByValue": True},
                                session=session)["result"]["value"])
        png = call("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True}, session=session)
        import base64
        with open(shot, "wb") as f:
            f.write(base64.b64decode(png["data"]))
        # Let late console or network events arrive.
        t_end = time.time() + 0.5
        while time.time() < t_end:
            try:
                call("Runtime.evaluate", {"expression": "1"}, session=session)
            except Exception:
                break
            time.sleep(0.1)
    except TimeoutError:
        print("chromium did not answer within 60 s", file=sys.stderr)
        proc.kill()
        sys.exit(3)
    finally:
        try:
            out.write(json.dumps({"id": 999999, "method": "Browser.close"}).encode() + b"\0")
        except Exception:
            pass
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
        shutil.rmtree(profile, ignore_errors=True)

    console, requests, dialogs = [], [], []
    for e in events:
        m, p = e.get("method"), e.get("params", {})
        if m == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            console.append(" ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", [])))
        elif m == "Runtime.exceptionThrown":
            console.append(p.get("exceptionDetails", {}).get("text", "exception"))
        elif m == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
            console.append(p["entry"].get("text", ""))
        elif m == "Network.requestWillBeSent":
            requests.append(p.get("request", {}).get("url", "")[:200])
        elif m == "Page.javascriptDialogOpening":
            dialogs.append(p.get("message", ""))
    found.update(console_errors=console, requests=requests, dialogs=dialogs, screenshot=shot)
    print(json.dumps(found))


if __name__ == "__main__":
    main()
