"""Support for long jobs on top of the env: atomic writes, versions and run folders (``runs``), MP4 videos of
a workcell's motion (``video``)."""
