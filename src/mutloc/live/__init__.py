"""Live operation over DDS with ROS 2's conventions (SPEC "Live operation"):
the messages (:mod:`mutloc.live.messages`), a node per robot, the localizer.
Needs the ``live`` extra (cyclonedds) for anything that touches the wire."""
