#!/usr/bin/env bash
# Make a private CA and certificates for a Shepherd deployment with mutual TLS.
# Usage: deploy/security/gen-certs.sh OUT_DIR [ROUTER_HOST ...]
#   OUT_DIR/ca.pem, ca.key      the certificate authority (keep ca.key offline)
#   OUT_DIR/router.{pem,key}    the router (SANs: localhost, 127.0.0.1 and ROUTER_HOSTs)
#   OUT_DIR/robot.{pem,key}     the wheeled robot (vision host): CN=robot
#   OUT_DIR/laptop.{pem,key}    the laptop (mission controller): CN=laptop
#   OUT_DIR/viewer.{pem,key}    a read-only observer: CN=viewer
#   OUT_DIR/credentials.txt     user:password lines for the router (random passwords)
#   OUT_DIR/{router,robot,laptop,viewer}.json5  native Zenoh configs: mutual TLS, user and
#                               password, and (router) the access control of acl.json5
# Needs openssl. Certificates are valid for 825 days; keys are EC P-256.
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
out=${1:?usage: gen-certs.sh OUT_DIR [ROUTER_HOST ...]}
shift || true
mkdir -p "$out"
cd "$out"
openssl ecparam -name prime256v1 -genkey -noout -out ca.key
openssl req -x509 -new -key ca.key -sha256 -days 825 -subj "/CN=shepherd-ca" -out ca.pem \
  -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign"
issue() {  # name, SANs
  local name=$1 sans=$2
  openssl ecparam -name prime256v1 -genkey -noout -out "$name.key.ec"
  openssl pkcs8 -topk8 -nocrypt -in "$name.key.ec" -out "$name.key"
  rm -f "$name.key.ec"
  openssl req -new -key "$name.key" -subj "/CN=$name" -out "$name.csr"
  printf "subjectAltName=%s\nextendedKeyUsage=serverAuth,clientAuth\nbasicConstraints=CA:FALSE\n" \
    "$sans" > "$name.ext"
  openssl x509 -req -in "$name.csr" -CA ca.pem -CAkey ca.key -CAcreateserial -days 825 \
    -sha256 -extfile "$name.ext" -out "$name.pem" 2>/dev/null
  rm -f "$name.csr" "$name.ext"
}
sans="DNS:localhost,IP:127.0.0.1"
for h in "$@"; do
  if [[ $h =~ ^[0-9.]+$ ]]; then sans="$sans,IP:$h"; else sans="$sans,DNS:$h"; fi
done
issue router "$sans"
for who in robot laptop viewer; do issue "$who" "DNS:$who"; done
dir=$(pwd)
: > credentials.txt
for who in router robot laptop viewer; do
  pw=$(openssl rand -hex 16)
  [ "$who" = router ] || echo "$who:$pw" >> credentials.txt
  if [ "$who" = router ]; then
    cat > router.json5 <<JSON
{
  mode: "router",
  listen: { endpoints: ["tls/0.0.0.0:7447"] },
  transport: {
    link: { tls: { root_ca_certificate: "$dir/ca.pem", listen_private_key: "$dir/router.key",
                   listen_certificate: "$dir/router.pem", enable_mtls: true } },
    auth: { usrpwd: { user: "router", password: "$pw", dictionary_file: "$dir/credentials.txt" } },
  },
  access_control: $(cat "$here/acl.json5"),
}
JSON
  else
    cat > "$who.json5" <<JSON
{
  transport: {
    link: { tls: { root_ca_certificate: "$dir/ca.pem", connect_private_key: "$dir/$who.key",
                   connect_certificate: "$dir/$who.pem", enable_mtls: true } },
    auth: { usrpwd: { user: "$who", password: "$pw" } },
  },
}
JSON
  fi
done
chmod 600 ./*.key credentials.txt ./*.json5
echo "certificates and Zenoh configs in $out: router, robot, laptop, viewer"
