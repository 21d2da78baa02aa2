#!/usr/bin/env bash
# Generate a site's certificates for Zenoh mutual TLS: a CA, the router's certificate and one
# client certificate per identity. The ACL (deploy/security/access_control.json5) grants rights
# by certificate common name, so the CN *is* the identity:
#   capsd-router   the topside router        capsd-asv      ASV computer services
#   capsd-locator  the topside locator       capsd-rov      ROV companion (mav_bridge)
#   capsd-laptop   a laptop: reads everything, writes nothing that moves the vehicle
# Usage: make-site-certs.sh OUTDIR [ROUTER_HOST...]   (localhost and 127.0.0.1 always included)
# Keys are EC P-256, valid 3 years; OUTDIR/ca.key must be kept off the vehicles. OUTDIR/fix.key
# (the fix signing key) goes to the topside (locator) and the ROV (mav_bridge) only.
set -euo pipefail
OUT=${1:?usage: make-site-certs.sh OUTDIR [ROUTER_HOST...]}
shift
# The router's certificate always names localhost and 127.0.0.1 (the topside locator and a
# laptop on the router's own machine connect there), plus every host name given.
HOSTS=(localhost 127.0.0.1 "$@")
mkdir -p "$OUT"
umask 077
days=1095
if [ ! -f "$OUT/ca.key" ]; then
  openssl ecparam -name prime256v1 -genkey -noout -out "$OUT/ca.key"
  openssl req -x509 -new -key "$OUT/ca.key" -sha256 -days $days -subj "/CN=capsd-site-ca" \
    -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" \
    -out "$OUT/ca.pem" 2>/dev/null
fi
san=""
for h in "${HOSTS[@]}"; do
  if [[ "$h" =~ ^[0-9.]+$ ]]; then san+="IP:$h,"; else san+="DNS:$h,"; fi
done
san=${san%,}
issue() {  # name, extra SAN, extended key usage
  local name=$1 alt=$2 usage=$3
  openssl ecparam -name prime256v1 -genkey -noout -out "$OUT/$name.key"
  openssl req -new -key "$OUT/$name.key" -subj "/CN=$name" -out "$OUT/$name.csr" 2>/dev/null
  printf 'basicConstraints=CA:FALSE\nkeyUsage=critical,digitalSignature,keyAgreement\nextendedKeyUsage=%s\nsubjectAltName=%s\n' "$usage" "$alt" > "$OUT/$name.ext"
  openssl x509 -req -in "$OUT/$name.csr" -CA "$OUT/ca.pem" -CAkey "$OUT/ca.key" -CAcreateserial \
    -days $days -sha256 -extfile "$OUT/$name.ext" -out "$OUT/$name.pem" 2>/dev/null
  rm -f "$OUT/$name.csr" "$OUT/$name.ext"
}
# The router serves TLS (and, as a peer of other routers, may connect); clients only connect.
issue capsd-router "$san" "serverAuth,clientAuth"
for identity in capsd-asv capsd-locator capsd-rov capsd-laptop; do
  issue "$identity" "DNS:$identity" "clientAuth"
done
chmod 644 "$OUT"/*.pem
# The site's fix key: the locator tags every fix with it, the ROV's bridge acts only on fixes
# it can check with it (capsd.signing). Owner-only, as the services require.
[ -f "$OUT/fix.key" ] || openssl rand -hex 32 > "$OUT/fix.key"
chmod 400 "$OUT/fix.key"
echo "certificates for $(printf '%s ' "${HOSTS[@]}")in $OUT: ca.pem, capsd-{router,asv,locator,rov,laptop}.{pem,key}; fix.key"
