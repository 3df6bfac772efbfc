"""The render's progress display: a bar (or plain lines off a terminal), and the filter that
keeps Blender's own status lines from tearing it."""

import os
import shutil
import threading
import time

from .common import flush_all


def format_duration(seconds):
    if seconds is None:
        return "?"
    seconds = int(round(max(0.0, seconds)))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class ProgressPrinter:
    """Draws the add-on's progress reports: a redrawn bar on a terminal, occasional plain lines otherwise."""

    def __init__(self, stream):
        self.stream = stream
        self.tty = stream.isatty()
        self.lock = threading.Lock()
        self.last = None
        self.last_draw = 0.0
        self.last_line = (-1, 0.0)  # (tenths done, time) of the last plain line
        self.bar = None  # the bar as drawn, while it is on screen

    def __call__(self, info):
        # Called from the render; a broken progress display must never break a render.
        try:
            with self.lock:
                self.update(dict(info))
        except Exception:
            pass

    def update(self, info):
        self.last = info
        done = int(info.get("samples_done") or 0)
        total = int(info.get("samples_total") or 0)
        elapsed = info.get("elapsed_s")
        eta = info.get("eta_s")
        now = time.monotonic()
        fraction = min(1.0, done / total) if total > 0 else 0.0
        finished = total > 0 and done >= total
        if self.tty:
            if now - self.last_draw < 0.1 and not finished:
                return
            width = shutil.get_terminal_size((80, 24)).columns
            text = f" {done}/{total} samples  {format_duration(elapsed)} elapsed  {format_duration(eta)} left"
            bar_width = max(10, min(40, width - len(text) - 4))
            filled = int(round(fraction * bar_width))
            self.bar = ("[" + "#" * filled + "-" * (bar_width - filled) + "]" + text)[: width - 1]
            self.stream.write("\r" + self.bar + "\x1b[K")
            self.stream.flush()
            self.last_draw = now
        else:
            tenths = int(fraction * 10)
            last_tenths, last_time = self.last_line
            if tenths == last_tenths and now - last_time < 15 and not finished:
                return
            if finished and last_tenths == 10:
                return
            self.stream.write(f"progress: {done}/{total} samples, {format_duration(elapsed)} elapsed, "
                              f"{format_duration(eta)} left\n")
            self.stream.flush()
            self.last_line = (10 if finished else tenths, now)

    def print_above(self, write):
        """Let other output through without tearing the bar: clear it, write, draw it again."""
        with self.lock:
            if self.bar is not None:
                self.stream.write("\r\x1b[K")
                self.stream.flush()
            write()
            if self.bar is not None:
                self.stream.write("\r" + self.bar)
                self.stream.flush()

    def finish(self):
        with self.lock:
            if self.bar is not None:
                self.stream.write("\n")
                self.stream.flush()
                self.bar = None


def write_all(fd, data):
    while data:
        data = data[os.write(fd, data):]


class StatusLineFilter:
    """In background mode Blender prints 'Fra:1 Mem:... | Time:...' on stdout for every status update
    (once per pass): while our progress display is up, drop those and pass everything else through."""

    def __init__(self, progress):
        self.progress = progress
        self.saved = None

    def start(self):
        flush_all()
        self.saved = os.dup(1)
        read_end, write_end = os.pipe()
        os.dup2(write_end, 1)
        os.close(write_end)
        self.thread = threading.Thread(target=self.pump, args=(read_end,), name="pathlight-stdout", daemon=True)
        self.thread.start()

    def pump(self, read_end):
        with os.fdopen(read_end, "rb") as pipe:
            for line in pipe:
                if not line.startswith(b"Fra:"):
                    self.progress.print_above(lambda: write_all(self.saved, line))

    def stop(self):
        if self.saved is None:
            return
        flush_all()
        os.dup2(self.saved, 1)  # closes the pipe's last write end: the pump sees EOF and ends
        self.thread.join(timeout=5)
        os.close(self.saved)
        self.saved = None
