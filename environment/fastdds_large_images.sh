# Sourced with the workspace (colcon, via colcon.pkg): every process started from this shell -- camera
# driver, RViz, Nav2 -- sends large messages through a 64 MB shared-memory segment instead of fragmented
# UDP. Only when no Fast DDS profile is set already: the user's own profile always wins.
if [ -z "${FASTRTPS_DEFAULT_PROFILES_FILE:-}" ] && [ -z "${FASTDDS_DEFAULT_PROFILES_FILE:-}" ]; then
  export FASTRTPS_DEFAULT_PROFILES_FILE="$COLCON_CURRENT_PREFIX/share/stereo_depth/config/fastdds_large_images.xml"
  export FASTDDS_DEFAULT_PROFILES_FILE="$FASTRTPS_DEFAULT_PROFILES_FILE"
fi
