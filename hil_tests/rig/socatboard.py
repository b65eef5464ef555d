"""A MicroPython process on a pty made by socat: the simulated board mpremote talks to.

The interpreter is the one TCOMP_MICROPYTHON chooses (hil_tests/rig/interpreters.py).

``socat PTY,link=LINK,raw,echo=0 EXEC:"micropython ...",pty,stderr,setsid,ctty,raw,echo=0``
with the board's flash directory as working directory. With no script the
process is a REPL (flash it with ``mpremote connect LINK resume ...``:
without ``resume`` mpremote's soft reset would end the process); with
``main.py`` it is the board booting from its flash.
"""
import os
import shlex
import shutil
import signal
import subprocess
import time

from hil_tests.rig import interpreters
from hil_tests.rig.harness import MP_DIR, RigError


class SocatBoard:
    def __init__(self, flash, link, script=None, world_spec=None, heap=None):
        self.flash = flash
        self.link = link
        self.script = script
        self.world_spec = world_spec
        self.heap = heap
        self.proc = None

    def start(self, timeout=10.0):
        socat = shutil.which("socat")
        if socat is None:
            raise RigError("socat is needed for a socat board")
        try:
            cmd = interpreters.get().argv(self.heap) + ([self.script] if self.script else [])
        except interpreters.InterpreterMissing as e:
            raise RigError(str(e))
        env = dict(os.environ)
        # the board's ROM: the simulated machine module; its flash (cwd) holds everything else
        # (hil_tests only, through a symlink: the repository's firmware/ must not shadow the flashed one)
        rom = os.path.join(os.path.dirname(os.path.abspath(self.flash)), "rom")
        os.makedirs(rom, exist_ok=True)
        if not os.path.lexists(os.path.join(rom, "hil_tests")):
            os.symlink(os.path.dirname(MP_DIR), os.path.join(rom, "hil_tests"))
        env["MICROPYPATH"] = ".:" + MP_DIR + ":" + rom
        if self.world_spec:
            env["TCOMP_HIL_WORLD"] = self.world_spec
        if os.path.lexists(self.link):
            os.unlink(self.link)
        self.proc = subprocess.Popen(
            [socat, "PTY,link=%s,raw,echo=0" % self.link,
             "EXEC:%s,pty,stderr,setsid,ctty,raw,echo=0" % shlex.quote(" ".join(cmd))],
            cwd=self.flash, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
        end = time.monotonic() + timeout
        while not os.path.exists(self.link):
            if self.proc.poll() is not None or time.monotonic() > end:
                raise RigError("socat did not create %s: %s" % (self.link, self.proc.stderr.read().decode()))
            time.sleep(0.02)
        return self

    def stop(self):
        if self.proc and self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        self.proc = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
