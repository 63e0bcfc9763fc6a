"""`lrr-explorer`: the desktop explorer.

    lrr-explorer [--target id008 --pose elbowBentLf --strategy nearest --pose-b kneeBentLf --blend 0.3
                  --magnitude 1.0 --compare --mesh my.obj --session s.json]
    lrr-explorer --screenshot out.png [...]    render the window once, write the PNG and exit

Needs a display (an X server; under CI `xvfb-run -a lrr-explorer ...`).
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from latent_model.runtime import keep_freed_memory, short_thread_spin  # noqa: E402

# Predictions run in a worker thread while the UI thread renders: OpenMP's default long spin-wait
# makes idle torch threads compete with rendering on a small CPU. Before torch is imported.
short_thread_spin()
keep_freed_memory()  # the decoder's temporaries are reused, not page-faulted in at every slider step


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="lrr-explorer", description="LatentReRig explorer: source | prediction | ground truth")
    ap.add_argument("--target", help="held-out identity (e.g. id008) to show first")
    ap.add_argument("--kind", default="neutral_to_pose", help="pair kind (default neutral_to_pose)")
    ap.add_argument("--pose", default="elbowBentLf", help="pose A (default elbowBentLf)")
    ap.add_argument("--pose-b", help="pose B to blend toward")
    ap.add_argument("--blend", type=float, default=0.0, help="blend A -> B in [0, 1]")
    ap.add_argument("--magnitude", type=float, default=1.0, help="delta magnitude in [0, 2]")
    ap.add_argument("--strategy", default="mean", help="mean (default), nearest or identity:<id>")
    ap.add_argument("--displacement", action="store_true", help="colour the prediction by displacement, not error")
    ap.add_argument("--compare", action="store_true", help="compare mean vs nearest side by side")
    ap.add_argument("--mesh", help="open this mesh file and make it the target")
    ap.add_argument("--session", help="load a saved session (JSON)")
    ap.add_argument("--tab", type=int, default=0, choices=(0, 1, 2), help="heatmap tab to show (2 = noise floor)")
    ap.add_argument("--screenshot", help="render once, save this PNG and exit")
    ap.add_argument("--size", default="1680x900", help="window size WxH (default 1680x900)")
    ap.add_argument("--timeout", type=float, default=600.0, help="--screenshot gives up after this many seconds")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if os.environ.get("QT_QPA_PLATFORM") == "offscreen":
        print("lrr-explorer: QT_QPA_PLATFORM=offscreen leaves the 3D views blank; run under an X server "
              "(e.g. xvfb-run -a lrr-explorer ...)", file=sys.stderr)
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY") and sys.platform.startswith("linux"):
        print("lrr-explorer: no display; run it on a desktop or under Xvfb: xvfb-run -a lrr-explorer ...", file=sys.stderr)
        return 2
    from latent_model.transfer import parse_strategy

    from explorer.session import Selection, SessionError

    try:
        sel = Selection.from_dict(dict(kind=args.kind, pose=args.pose, pose_b=args.pose_b, blend=args.blend,
                                       magnitude=args.magnitude, strategy=parse_strategy(args.strategy),
                                       colour="displacement" if args.displacement else "error", compare=args.compare,
                                       **({"target": args.target} if args.target else {})))
        w, h = (int(x) for x in args.size.lower().split("x"))
    except (ValueError, SessionError) as e:
        print(f"lrr-explorer: error: {e}", file=sys.stderr)
        return 2

    from PySide6.QtCore import QTimer
    from PySide6.QtWidgets import QApplication

    from explorer.main_window import MainWindow

    app = QApplication.instance() or QApplication(sys.argv[:1])
    win = MainWindow(sel)
    win.resize(w, h)
    win.heatmaps.setCurrentIndex(args.tab)
    win.show()
    status = {"rc": 0, "startup": [args.mesh, args.session]}

    def after_load(name: str, _result) -> None:
        if name != "load":
            return
        if args.mesh:
            win.open_path(args.mesh)
        if args.session:
            win.load_session(args.session)

    win.worker.job_done.connect(after_load)

    if args.screenshot:
        out = Path(args.screenshot)
        out.parent.mkdir(parents=True, exist_ok=True)
        import time

        started = time.perf_counter()
        timer = QTimer(win)

        def poll() -> None:
            try:
                _poll()
            except Exception as e:  # noqa: BLE001 - report and leave, never hang
                timer.stop()
                print(f"lrr-explorer: error: {e}", file=sys.stderr)
                status["rc"] = 1
                app.quit()

        def _poll() -> None:
            wants_noise = args.tab == 2 and win.heatmaps.noise_target is None and win.last_error is None
            wants_mesh = bool(args.mesh) and (win.state is None or win.state.target not in (win.worker.session.meshes if win.worker.session else {}))
            if win.last_error and win.state is None:
                print(f"lrr-explorer: error: {win.last_error}", file=sys.stderr)
                status["rc"] = 1
                app.quit()
            elif win.is_settled() and not wants_noise and not (wants_mesh and win.last_error is None):
                timer.stop()
                win.views.render()
                app.processEvents()
                win.save_screenshot(out)
                print(f"wrote {out}")
                app.quit()
            elif time.perf_counter() - started > args.timeout:
                print(f"lrr-explorer: gave up after {args.timeout:.0f} s without a prediction on screen", file=sys.stderr)
                status["rc"] = 1
                app.quit()

        timer.timeout.connect(poll)
        timer.start(200)
    app.exec()
    if args.screenshot:
        win.close()
    return status["rc"]


if __name__ == "__main__":
    raise SystemExit(main())
