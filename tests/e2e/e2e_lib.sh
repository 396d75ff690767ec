# shellcheck shell=bash disable=SC2034  # src: set here for the sourcing script
# Shared by the host end-to-end scripts (source it; bash):
#   make_skin_map OUT.yaml [touchsim options...]
#       the true skin map skinbus-touchsim puts on the project's robot (cylinder patches on the
#       forearms, flat ones on the chest), every patch with the shipped model; $bin/skinbus-touchsim
#   use_loopback_dds
#       Cyclone DDS on loopback only (tools/dds/loopback.xml), unless CYCLONEDDS_URI is set
src=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
make_skin_map() {
  local out=$1 dir
  shift
  dir=$(mktemp -d)
  "$bin/skinbus-touchsim" --robot "$src/body_map/robots/skinbot.urdf" --out-dir "$dir" \
    --model "$src/estimators/models/nominal_seed_cnn" "$@" >/dev/null
  sed -e "s|^robot: .*|robot: \"$src/body_map/robots/skinbot.urdf\"|" "$dir/truth.yaml" >"$out"
  rm -rf "$dir"
}
use_loopback_dds() {
  export CYCLONEDDS_URI=${CYCLONEDDS_URI:-file://$src/tools/dds/loopback.xml}
}
