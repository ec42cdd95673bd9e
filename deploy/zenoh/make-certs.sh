#!/usr/bin/env bash
# Make a private CA and a router certificate for Zenoh TLS (development / testing).
# Usage: deploy/zenoh/make-certs.sh DIR [HOSTNAME_OR_IP...]   (default: localhost 127.0.0.1)
# The router certificate's SAN must name every address clients dial (ZENOH_NOTES: IP:/DNS:).
set -euo pipefail
dir=${1:?usage: make-certs.sh DIR [NAMES...]}; shift || true
if [ $# -eq 0 ]; then names=(localhost 127.0.0.1); else names=("$@"); fi
san=""
for n in "${names[@]}"; do
    if [[ $n =~ ^[0-9.]+$ ]]; then san+="IP:$n,"; else san+="DNS:$n,"; fi
done
mkdir -p "$dir" && cd "$dir"
openssl req -x509 -newkey rsa:2048 -nodes -keyout ca-key.pem -out ca.pem -days 365 -subj "/CN=limbstream-ca" 2>/dev/null
openssl req -newkey rsa:2048 -nodes -keyout router-key.pem -out router.csr -subj "/CN=limbstream-router" 2>/dev/null
openssl x509 -req -in router.csr -CA ca.pem -CAkey ca-key.pem -CAcreateserial -out router.pem -days 365 \
    -extfile <(printf "subjectAltName=%s\nbasicConstraints=CA:FALSE\nkeyUsage=digitalSignature,keyEncipherment\nextendedKeyUsage=serverAuth" "${san%,}") 2>/dev/null
rm -f router.csr ca.srl
chmod 600 ca-key.pem router-key.pem
echo "made $dir/{ca.pem,router.pem,router-key.pem} for ${names[*]}"
