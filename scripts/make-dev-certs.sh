#!/usr/bin/env bash
# Makes a development CA and a server certificate it signs, with openssl:
#   scripts/make-dev-certs.sh DIR [NAME...]
# writes DIR/ca.crt, DIR/ca.key, DIR/tls.crt and DIR/tls.key (the names
# Kubernetes TLS Secrets and the shipped configurations use) for the DNS
# names and IP addresses given (default: localhost humem 127.0.0.1), valid
# for 30 days. For development, tests and the compose demo only: the key is
# readable by all (the container's user must read a bind-mounted file); a
# real deployment gets its certificate from its own CA (e.g. cert-manager).
set -euo pipefail
dir=${1:?usage: $0 DIR [NAME...]}
shift
names=("$@")
[ ${#names[@]} -gt 0 ] || names=(localhost humem 127.0.0.1)
mkdir -p "$dir"
san=""
for name in "${names[@]}"; do
    if [[ $name =~ ^[0-9.]+$ || $name == *:* ]]; then san+="IP:$name,"; else san+="DNS:$name,"; fi
done
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days 30 \
    -subj "/CN=HuMem development CA" -keyout "$dir/ca.key" -out "$dir/ca.crt" 2>/dev/null
openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -subj "/CN=${names[0]}" \
    -keyout "$dir/tls.key" -out "$dir/tls.csr" 2>/dev/null
printf 'subjectAltName=%s\nbasicConstraints=CA:FALSE\nextendedKeyUsage=serverAuth\n' "${san%,}" >"$dir/tls.ext"
openssl x509 -req -in "$dir/tls.csr" -CA "$dir/ca.crt" -CAkey "$dir/ca.key" -CAcreateserial \
    -days 30 -extfile "$dir/tls.ext" -out "$dir/tls.crt" 2>/dev/null
rm -f "$dir/tls.csr" "$dir/tls.ext" "$dir/ca.srl"
chmod 0644 "$dir/tls.key"
echo "make-dev-certs: $dir/ca.crt, $dir/tls.crt and $dir/tls.key for ${names[*]}"
