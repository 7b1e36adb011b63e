"""A viva-genicam fake GigE Vision camera as its own process: ``python viva_peer.py W H ADDRESS``.

Run as a process (started from inside the test's network namespace) rather than in the test
process: the library's worker threads keep the namespace they started in, so a second fake in
a later test's namespace would be unreachable. Prints ``ready`` once listening; ends on
SIGTERM or when its standard input closes.
"""

from __future__ import annotations

import signal
import sys
import threading

from viva_genicam.testing import FakeGigeCamera

width, height, address = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
camera = FakeGigeCamera(width, height, bind_ip=address)
camera.start()
done = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: done.set())
threading.Thread(target=lambda: (sys.stdin.read(), done.set()), daemon=True).start()
print("ready", flush=True)
done.wait(timeout=600)  # bounded: never outlives a test run
camera.stop()
