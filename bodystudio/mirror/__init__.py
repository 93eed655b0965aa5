"""The virtual mirror (issue 12): real-time reshaping of a person in Kinect RGB-D video."""
