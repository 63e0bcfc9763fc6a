"""Benchmark the explorer's scrubbing: slider value change -> new prediction on screen (request,
coalescing worker, Transfer.predict, points/scalars set in place, VTK render), median over
several slider moves; and the prediction part of each (Transfer.predict, timed by the session
in the app's model thread: only that thread runs torch, as in the app — a second thread that
ran torch would give OpenMP more threads than cores and throttle its spin-waiting).
Targets: <= 120 ms and <= 40 ms (software rendering under Xvfb). Prints medians; never asserts.

Needs an X server:  xvfb-run -a python bench/bench_explorer.py [--moves 20] [--threads 1]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time

from latent_model.runtime import keep_freed_memory, short_thread_spin  # noqa: E402

short_thread_spin()  # as the app does (explorer/app.py), before torch
keep_freed_memory()  # as the app does


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--moves", type=int, default=20)
    ap.add_argument("--threads", type=int, default=2, help="torch threads (default 2, as the app on this machine)")
    ap.add_argument("--pose", default="elbowBentLf")
    ap.add_argument("--kind", default="neutral_to_pose", help="pair kind (skinning_to_skinning_plus_blendshape: the "
                                                              "corrective fields)")
    args = ap.parse_args()
    import torch
    from PySide6.QtCore import QEventLoop, QTimer
    from PySide6.QtWidgets import QApplication

    from explorer.main_window import MainWindow
    from explorer.selection import Selection

    torch.set_num_threads(args.threads)
    app = QApplication.instance() or QApplication(sys.argv[:1])
    t0 = time.perf_counter()
    win = MainWindow(Selection(pose=args.pose, kind=args.kind))
    win.show()  # at the default size (fits 1366x768), as a user gets it

    def wait(cond, timeout=600.0):
        end = time.perf_counter() + timeout
        while not cond():
            app.processEvents()
            time.sleep(0.001)
            if time.perf_counter() > end:
                raise SystemExit("timed out waiting for the window")

    wait(lambda: win.is_settled())
    print(f"startup to first prediction on screen + heatmaps: {time.perf_counter() - t0:.1f} s "
          f"(window {win.width()}x{win.height()})")
    # slider -> screen, one move at a time (each waits for its prediction to be drawn)
    lat, model, draw, dec = [], [], [], []
    for k in range(args.moves):
        value = 60 + (k * 37) % 140
        if value == win.controls.magnitude.value():
            value += 1
        # wait inside a Qt event loop, as the app's UI thread does: a Python polling loop would
        # hold the GIL the model thread needs between its torch ops and slow it down
        n = len(win.update_ms)
        loop = QEventLoop()
        win.prediction_shown.connect(loop.quit)
        QTimer.singleShot(30000, loop.quit)
        t = time.perf_counter()
        win.controls.magnitude.setValue(value)
        loop.exec()
        win.prediction_shown.disconnect(loop.quit)
        wait(lambda: len(win.update_ms) > n)  # the Qt paint that renders the prediction view
        lat.append((time.perf_counter() - t) * 1000)
        model.append(win.state.seconds * 1000)
        dec.append(win.state.seconds_predict * 1000)
        draw.append(win.draw_ms[-1])
    # a fast scrub: 50 values as quickly as Qt delivers them
    n = len(win.update_ms)
    t = time.perf_counter()
    for v in range(100, 200, 2):
        win.controls.magnitude.setValue(v)
        app.processEvents()
    wait(lambda: win.worker.idle and win.state.selection.magnitude == 1.98)
    scrub = time.perf_counter() - t
    print(f"slider -> new prediction on screen: median {statistics.median(lat):.0f} ms "
          f"(min {min(lat):.0f}, max {max(lat):.0f}; {args.moves} moves; target <= 120 ms)")
    print(f"  of which: model thread (Session.compute) median {statistics.median(model):.0f} ms, "
          f"points set in the views median {statistics.median(draw):.0f} ms, then one render at the paint")
    print(f"Transfer.predict in the model thread, as the app runs it: median "
          f"{statistics.median(dec):.0f} ms (target <= 40 ms)")
    print(f"fast scrub of 50 slider steps: {scrub:.2f} s, {len(win.update_ms) - n} predictions drawn "
          f"(the rest coalesced away)")
    win.close()


if __name__ == "__main__":
    main()
