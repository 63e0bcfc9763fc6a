"""`lrr-explorer`: the desktop explorer.

    lrr-explorer [--target id008 --pose elbowBentLf --strategy nearest --pose-b kneeBentLf --blend 0.3 --view side
                  --magnitude 1.0 --compare --mesh my.obj --session s.json
                  --example-neutral A.obj --example-posed A1.obj]
    lrr-explorer --screenshot out.png [...]    render the window once, write the PNG and exit

Needs a display (an X server; under CI `xvfb-run -a lrr-explorer ...`).
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from latent_model.runtime import keep_freed_memory, short_thread_spin  # noqa: E402
from latent_model.types import MAGNITUDE_RANGE  # noqa: E402

# Predictions run in a worker thread while the UI thread renders: OpenMP's default long spin-wait
# makes idle torch threads compete with rendering on a small CPU. Before torch is imported.
short_thread_spin()
keep_freed_memory()  # the decoder's temporaries are reused, not page-faulted in at every slider step


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="lrr-explorer", description="LatentReRig explorer: source | prediction | ground truth")
    ap.add_argument("--target", help="held-out identity (e.g. id008) to show first")
    ap.add_argument("--kind", default="neutral_to_pose", help="pair kind (default neutral_to_pose); with --mesh, the mesh is "
                    "taken as its source: a skinned pose for skinning_to_skinning_plus_blendshape")
    ap.add_argument("--pose", default="elbowBentLf", help="pose A (default elbowBentLf)")
    ap.add_argument("--pose-b", help="pose B to blend toward")
    ap.add_argument("--blend", type=float, default=0.0, help="blend A -> B in [0, 1]")
    ap.add_argument("--magnitude", type=float, default=1.0, help="delta magnitude in [%g, %g]" % MAGNITUDE_RANGE)
    ap.add_argument("--strategy", default="mean", help="mean (default), nearest or identity:<id>")
    ap.add_argument("--displacement", action="store_true", help="colour the prediction by displacement, not error")
    ap.add_argument("--compare", action="store_true", help="compare mean vs nearest side by side")
    ap.add_argument("--mesh", help="open this mesh file and make it the target")
    ap.add_argument("--session", help="load a saved session (JSON)")
    ap.add_argument("--example-neutral", help="condition on an example pair: a character's neutral mesh A")
    ap.add_argument("--example-posed", help="... and the same mesh deformed, A1 (A's vertices and triangles)")
    ap.add_argument("--focus", default="auto", help="what the views frame: auto (what the pose moves, close up when "
                    "small: default), body, head, hand_left or hand_right")
    ap.add_argument("--view", default="front", choices=("front", "side"), help="camera: front (default) or side")
    ap.add_argument("--tab", type=int, default=0, choices=(0, 1, 2), help="heatmap tab to show (2 = noise floor)")
    ap.add_argument("--screenshot", help="render once, save this PNG and exit (non-zero, with the error, if anything fails)")
    ap.add_argument("--size", default="1366x768",
                    help="window size WxH (default 1366x768), shrunk to fit the screen")
    ap.add_argument("--timeout", type=float, default=600.0, help="--screenshot gives up after this many seconds")
    return ap


def _fail(msg: str, rc: int = 2) -> int:
    print(f"lrr-explorer: error: {msg}", file=sys.stderr)
    return rc


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if os.environ.get("QT_QPA_PLATFORM") == "offscreen":
        print("lrr-explorer: QT_QPA_PLATFORM=offscreen leaves the 3D views blank; run under an X server "
              "(e.g. xvfb-run -a lrr-explorer ...)", file=sys.stderr)
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY") and sys.platform.startswith("linux"):
        print("lrr-explorer: no display; run it on a desktop or under Xvfb: xvfb-run -a lrr-explorer ...", file=sys.stderr)
        return 2
    from latent_model.meshio import load_example_pair, load_mesh

    from explorer.selection import Selection, read_session

    # everything the command line names is checked before the model loads: a bad file fails fast
    try:
        sel = Selection.from_dict(dict(kind=args.kind, pose=args.pose, pose_b=args.pose_b, blend=args.blend,
                                       magnitude=args.magnitude, strategy=args.strategy,
                                       colour="displacement" if args.displacement else "error", compare=args.compare,
                                       focus=args.focus,
                                       **({"target": args.target} if args.target else {})))
        try:
            w, h = (int(x) for x in args.size.lower().split("x"))
        except ValueError:
            raise ValueError(f"--size {args.size!r}: use WxH, e.g. 1366x768") from None
        mesh = None
        if args.mesh:
            if not Path(args.mesh).is_file():
                raise ValueError(f"{args.mesh}: no such mesh file")
            mesh = load_mesh(args.mesh)
        saved = read_session(args.session) if args.session else None
        example = (args.example_neutral, args.example_posed)
        if any(example) and not all(example):
            raise ValueError("--example-neutral and --example-posed go together (the mesh A and A deformed)")
        if all(example):
            load_example_pair(*example)  # a missing file or another topology fails before the model loads
    except (ValueError, OSError) as e:  # SessionError and MeshError are ValueErrors
        return _fail(str(e))

    from PySide6.QtCore import QTimer
    from PySide6.QtWidgets import QApplication

    from explorer.main_window import MainWindow

    app = QApplication.instance() or QApplication(sys.argv[:1])
    win = MainWindow(sel)
    win.fit_to_screen(w, h)
    win.heatmaps.setCurrentIndex(args.tab)
    win.show()
    status = {"rc": 0, "error": None}

    def after_load(_session) -> None:
        if mesh is not None:
            win.open_path(args.mesh, mesh, sel.kind)
        if saved is not None:
            win.restore_session(*saved)
        if all(example):
            win.open_example(*example)

    win.loaded.connect(after_load)

    def first_view(_state) -> None:  # the views frame the first mesh from the front; then the camera asked for
        win.prediction_shown.disconnect(first_view)
        win.views.set_view(args.view)

    if args.view != "front":
        win.prediction_shown.connect(first_view)

    if args.screenshot:
        out = Path(args.screenshot)
        import time

        started = time.perf_counter()
        timer = QTimer(win)
        # any error shown while rendering the screenshot fails the run (the image would not show
        # what was asked for); the first one is the one to report
        win.error_shown.connect(lambda msg: status.update(error=status["error"] or msg))

        def leave(rc: int, msg: str | None = None) -> None:
            timer.stop()
            if msg:
                print(f"lrr-explorer: error: {msg}", file=sys.stderr)
            status["rc"] = rc
            app.quit()

        def poll() -> None:
            try:
                _poll()
            except Exception as e:  # noqa: BLE001 - report and leave, never hang
                leave(1, str(e))

        def _poll() -> None:
            s = win.session
            if status["error"]:
                leave(1, status["error"])
            elif s is not None and win.is_settled() and _shows_what_was_asked(s):
                timer.stop()
                win.views.render()
                app.processEvents()
                win.save_screenshot(out)
                print(f"wrote {out}")
                leave(0)
            elif time.perf_counter() - started > args.timeout:
                leave(1, f"gave up after {args.timeout:.0f} s without a prediction on screen")

        def _shows_what_was_asked(s) -> bool:
            if s.pending_selection is not None or s.selection is None or s.state.selection.target != s.selection.target:
                return False
            if mesh is not None and not s.is_mesh(s.state.target):
                return False
            if all(example) and s.state.example is None:
                return False
            return args.tab != 2 or (s.noise is not None and s.noise.target == s.state.target)

        timer.timeout.connect(poll)
        timer.start(200)
    app.exec()
    if args.screenshot:
        win.close()
    return status["rc"]


if __name__ == "__main__":
    raise SystemExit(main())
