"""``mutloc node``: one robot's camera, its detections published over DDS as ROS 2 messages."""

from __future__ import annotations

import argparse

from ._common import LIVE, PROGRESS, RIG, live_domain, loopback_wanted, positive_float

ORDER = 80


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``node``."""
    p = subparsers.add_parser(
        "node", parents=[RIG, LIVE, PROGRESS],
        help="live: detect the other robots' markers in this robot's camera, publish them over DDS (ROS 2)",
        description="Run on each robot: takes the newest frame of the camera (frames the detector cannot keep up "
        "with are dropped and counted, never queued), finds the other robots' markers and publishes one "
        "mutloc_msgs/msg/Observations message per processed frame on /mutloc/NAME/observations, stamped with "
        "the frame's capture time (SPEC \"Live operation\"). A robot with several cameras: one --camera CAM=SOURCE "
        "per camera (each detected through its own lens in its own thread, messages with frame_id NAME/CAM), or one "
        "node per camera. Needs the live extra (cyclonedds).",
    )
    p.add_argument("--robot", required=True, metavar="NAME", help="the robot whose camera this is (a robot of the rig)")
    p.add_argument("--camera", required=True, action="append", metavar="[CAM=]SOURCE",
                   help="a camera device (/dev/video0 or 0), a GStreamer pipeline or stream URL (rtsp://...), a ROS 2 "
                        "image topic (ros:/p/image_raw, or .../compressed; its camera_info is checked against the "
                        "rig, or used: --camera-info), or a recorded video, image folder or bag (with --realtime). "
                        "A robot with several cameras (rig 'cameras:'): CAM=SOURCE, repeatable, one per camera this "
                        "process runs (each camera's frames detected through its own lens, its messages' frame_id "
                        "NAME/CAM); one process per camera works as well")
    p.add_argument("--realtime", nargs="?", const=1.0, type=positive_float, metavar="SPEED",
                   help="replay a recording as a camera: frames released at their own rate (times SPEED, default 1), "
                        "stamped with the wall-clock time of their scheduled release")
    p.add_argument("--loop", action="store_true", help="with --realtime: play the recording again and again")
    p.add_argument("--start-at", type=float, metavar="UNIX_TIME",
                   help="with --realtime: release the first frame at this wall-clock time (seconds since 1970), so "
                        "that the replays of several robots run in step")
    p.add_argument("--topic", action="append", metavar="[CAM=]TOPIC",
                   help="the image topic of a recorded bag; with several cameras one CAM=TOPIC per camera "
                        "(repeatable, e.g. --topic front=/p/front/image_raw --topic back=/p/back/image_raw)")
    p.add_argument("--camera-info", choices=("check", "use"), default="check",
                   help="a ROS image topic's camera_info: check it against the rig's camera of this robot and warn "
                        "when they differ (default), or use it: detect in the camera it describes (K, D plumb_bob or "
                        "rational_polynomial, width, height) and publish pixels re-expressed in the rig's camera "
                        "(same rays), so the localizer needs only the rig file")
    p.add_argument("--diagnostics", action="store_true",
                   help="also publish the node's own status on /diagnostics once a second")
    p.add_argument("--duration", type=positive_float, metavar="S", help="stop after S seconds")
    p.add_argument("--status-every", type=positive_float, default=5.0, metavar="S",
                   help="print a status line every S seconds (default 5; --no-progress: none)")
    return p


def run(args: argparse.Namespace) -> int:
    """Open the camera, join the DDS domain and publish until the source ends or Ctrl-C."""
    import sys

    from ..io import load_rig
    from ..live.cameras import camera_kind, open_camera
    from ..live.dds import Bus
    from ..live.node import Node, camera_arguments, camera_key, camera_topics, run_nodes

    rig = load_rig(args.rig)
    rig.robot(args.robot)  # an unknown robot: one line, before the camera opens
    cameras = camera_arguments(rig, args.robot, args.camera)  # unknown or missing camera names: one line
    topics = camera_topics(cameras, args.topic)
    domain = live_domain(args)

    def say(line: str) -> None:
        print(f"mutloc node: {line}", file=sys.stderr, flush=True)

    # Devices, streams and recordings are opened before joining DDS: a bad one fails at once.
    bus = Bus(domain, loopback=loopback_wanted(args)) if any(camera_kind(s) == "ros" for _, s in cameras) else None
    sources = []
    try:
        for (camera, spec), topic in zip(cameras, topics):
            sources.append(open_camera(spec, bus=bus, realtime=args.realtime, topic=topic, loop=args.loop,
                                       rig_camera=rig.mount(camera_key(rig, args.robot, camera)).camera,
                                       start_at=args.start_at, camera_info=args.camera_info))
        bus = bus or Bus(domain, loopback=loopback_wanted(args))
    except BaseException:
        for source in sources:
            source.close()
        if bus is not None:
            bus.close()
        raise
    try:
        nodes = []
        for (camera, _), source in zip(cameras, sources):
            nodes.append(Node(args.rig, args.robot, source, bus, diagnostics=args.diagnostics, report=say,
                              camera=camera))
            say(f"robot {args.robot}, camera {source.name}"
                + (f" ({nodes[-1].key})" if nodes[-1].key != args.robot else "")
                + f", publishing on {nodes[-1].topic} (DDS domain {domain}"
                f"{', loopback' if loopback_wanted(args) else ''})")
        try:
            all_stats = run_nodes(nodes, duration=args.duration,
                                  status_every=args.status_every if args.progress else None)
        except KeyboardInterrupt:
            for node in nodes:
                if node.stats.stages:
                    print(node.stats.stage_line(), file=sys.stderr, flush=True)
                print(f"interrupted: {node.stats.summary()}", file=sys.stderr, flush=True)
            return 130
        for stats in all_stats:
            if stats.stages:
                print(stats.stage_line(), flush=True)
            print(stats.summary(), flush=True)
        return 0
    finally:
        for source in sources:
            source.close()
        bus.close()
