#!/usr/bin/env bash
# Install CAP-SD for one role of a site into a virtual environment and enable its units.
#   asv      ASV computer: asv_pose, tim5xx, oculus, sonar_detect (torch CPU), ros_input,
#            and the bridge to its ArduRover (asv role)
#   rov      ROV companion (BlueOS Pi): mav_bridge only; no torch, scipy or opencv
#   topside  topside computer: the router, the locator and the ASV follower (and tools)
# Usage: deploy/install.sh ROLE [--prefix /opt/capsd] [--etc /etc/capsd]
#                               [--unit-dir /etc/systemd/system] [--no-enable] [--no-user]
#                               [--certs DIR]
# --certs DIR: the site's certificates (deploy/security/make-site-certs.sh DIR): the CA and this
# role's identities go to ETC/certs, each key readable by the service user only; fix.key (the
# fix signing key) only to the roles that sign or check fixes and commands (all three).
# Existing configs in --etc are kept (an upgrade never overwrites a site's settings).
set -euo pipefail
ROLE=${1:?usage: install.sh asv|rov|topside [options]}
shift
PREFIX=/opt/capsd ETC=/etc/capsd UNIT_DIR=/etc/systemd/system ENABLE=1 MAKE_USER=1 CERTS=
while [ $# -gt 0 ]; do
  case "$1" in
    --prefix) PREFIX=$2; shift 2 ;;
    --etc) ETC=$2; shift 2 ;;
    --unit-dir) UNIT_DIR=$2; shift 2 ;;
    --no-enable) ENABLE=0; shift ;;
    --no-user) MAKE_USER=0; shift ;;
    --certs) CERTS=$2; shift 2 ;;
    *) echo "install.sh: unknown option '$1'" >&2; exit 2 ;;
  esac
done
case "$ROLE" in
  asv) EXTRAS="asv,detect,ros,rov"
       UNITS="asv-pose tim5xx oculus sonar-detect ros-input asv-bridge"
       IDENTITIES="capsd-asv" SECRETS="fix.key" ;;
  rov) EXTRAS="rov"; UNITS="mav-bridge" IDENTITIES="capsd-rov" SECRETS="fix.key" ;;
  topside) EXTRAS="topside"; UNITS="router locator asv-follow"
           IDENTITIES="capsd-router capsd-locator" SECRETS="fix.key" ;;
  *) echo "install.sh: role must be asv, rov or topside, not '$ROLE'" >&2; exit 2 ;;
esac
REPO=$(cd "$(dirname "$0")/.." && pwd)
# A system Python by default: the service user must be able to run what the venv links to
# (a pyenv or conda Python under an admin's home is not readable by it).
if [ -n "${PYTHON:-}" ]; then PY=$PYTHON
elif [ -x /usr/bin/python3.11 ]; then PY=/usr/bin/python3.11
elif command -v python3.11 >/dev/null 2>&1; then PY=python3.11
else PY=python3
fi
echo "installing CAP-SD ($ROLE) into $PREFIX/venv"
mkdir -p "$PREFIX" "$ETC" "$UNIT_DIR"
[ -x "$PREFIX/venv/bin/python" ] || "$PY" -m venv "$PREFIX/venv"
"$PREFIX/venv/bin/python" -m pip install --quiet --disable-pip-version-check "$REPO[$EXTRAS]"
if [ "$MAKE_USER" = 1 ] && ! id capsd >/dev/null 2>&1; then
  useradd --system --no-create-home --shell /usr/sbin/nologin capsd
fi
if [ "$MAKE_USER" = 1 ] && [ "$(id -u)" = 0 ] && command -v runuser >/dev/null 2>&1; then
  # The units run as capsd: it must reach the venv and the Python the venv links to.
  if ! (cd / && runuser -u capsd -- "$PREFIX/venv/bin/python" -c "import capsd") 2>/dev/null; then
    echo "install.sh: the service user capsd cannot run $PREFIX/venv/bin/python" \
      "(-> $(readlink -f "$PREFIX/venv/bin/python")): a directory on the way is not open to" \
      "it, or the venv was made from a Python under someone's home; e.g." \
      "rm -r $PREFIX/venv; PYTHON=/usr/bin/python3.11 $0 $ROLE ..." >&2
    exit 1
  fi
fi
for unit in $UNITS; do
  service=${unit//-/_}
  src="$REPO/deploy/roles/$ROLE/$service.yaml"  # joined the way this role joins
  [ -f "$src" ] || src="$REPO/deploy/config/$service.yaml"
  if [ -f "$src" ] && [ ! -f "$ETC/$service.yaml" ]; then cp "$src" "$ETC/$service.yaml"; fi
  sed -e "s#/opt/capsd/venv#$PREFIX/venv#g" -e "s#/etc/capsd#$ETC#g" \
    "$REPO/deploy/systemd/capsd-$unit.service" > "$UNIT_DIR/capsd-$unit.service"
done
[ -f "$ETC/capsd.env" ] || printf '# Site settings for the CAP-SD units (KEY=value).\n' > "$ETC/capsd.env"
if [ "$ROLE" = topside ] && [ ! -f "$ETC/access_control.json5" ]; then
  cp "$REPO/deploy/security/access_control.json5" "$ETC/access_control.json5"
fi
if [ -n "$CERTS" ]; then
  [ -f "$CERTS/ca.pem" ] || { echo "install.sh: no ca.pem in '$CERTS'" >&2; exit 2; }
  owner=root; id capsd >/dev/null 2>&1 && owner=capsd
  install -d -m 0750 -o root -g "$owner" "$ETC/certs"
  install -m 0444 "$CERTS/ca.pem" "$ETC/certs/ca.pem"
  for identity in $IDENTITIES; do
    for f in "$identity.pem" "$identity.key"; do
      [ -f "$CERTS/$f" ] || { echo "install.sh: no $f in '$CERTS'" >&2; exit 2; }
    done
    install -m 0444 "$CERTS/$identity.pem" "$ETC/certs/$identity.pem"
    install -m 0400 -o "$owner" "$CERTS/$identity.key" "$ETC/certs/$identity.key"
  done
  for f in $SECRETS; do
    [ -f "$CERTS/$f" ] || { echo "install.sh: no $f in '$CERTS'" >&2; exit 2; }
    install -m 0400 -o "$owner" "$CERTS/$f" "$ETC/certs/$f"
  done
  echo "certificates: $IDENTITIES${SECRETS:+ and $SECRETS} in $ETC/certs (keys 0400, $owner)"
fi
if [ "$ENABLE" = 1 ] && [ -d /run/systemd/system ]; then
  systemctl daemon-reload
  for unit in $UNITS; do systemctl enable "capsd-$unit.service"; done
elif [ "$ENABLE" = 1 ]; then
  # A container or a machine booted without systemd: systemctl exists but cannot enable.
  echo "systemd is not running here: units written but not enabled (their ExecStart lines run them)"
fi
echo "done: units $(printf 'capsd-%s ' $UNITS)in $UNIT_DIR, configs in $ETC"
