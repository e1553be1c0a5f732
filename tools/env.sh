# Source me (bash): activates .venv and the colcon install/ of humanoid_reach_ros.
# Works from any directory; safe to source twice.
_hr_root=$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")/.." && pwd)
# shellcheck disable=SC1091
. "$_hr_root/.venv/bin/activate"
export AMENT_PREFIX_PATH=$_hr_root/.venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}
if [ -f "$_hr_root/install/local_setup.bash" ]; then
  # shellcheck disable=SC1091
  . "$_hr_root/install/local_setup.bash"
fi
export PYTHONPATH=$_hr_root${PYTHONPATH:+:$PYTHONPATH}
# The package's executables: what `ros2 run humanoid_reach_ros <exe>` runs on a full install.
export PATH=$_hr_root/install/humanoid_reach_ros/lib/humanoid_reach_ros:$PATH
# Keep every graph started from here on this machine only (docs/operator.md: graph isolation).
export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
# Point clouds are larger than Fast DDS's built-in 0.5 MB shared-memory segment: the package's
# profile gives 8 MB (config/fastdds.xml; docs/operator.md: large messages). A profile of your own wins.
export FASTRTPS_DEFAULT_PROFILES_FILE=${FASTRTPS_DEFAULT_PROFILES_FILE:-$_hr_root/config/fastdds.xml}
unset _hr_root
