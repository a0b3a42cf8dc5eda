#!/bin/sh
# Certificates for a local Trevi farm with its own certificate authority.
#
#   deploy/make-certs.sh OUTDIR [HOSTNAME|IP ...]
#
# Writes into OUTDIR (created if needed):
#   ca.pem           the CA certificate: give it to workers and submitters
#                    (--tls-ca / TREVI_TLS_CA)
#   ca.key           the CA's private key: keep it to yourself (it signs)
#   coordinator.pem  the coordinator's certificate (--tls-cert / TREVI_TLS_CERT)
#   coordinator.key  its private key (--tls-key / TREVI_TLS_KEY)
#
# The coordinator's certificate is valid for localhost, 127.0.0.1, ::1 and
# coordinator (the docker-compose and Kubernetes service name) plus every
# name or IP address given, so clients must reach it by one of those names.
# An existing ca.pem/ca.key in OUTDIR is reused, so running the script again
# with more names issues a new coordinator certificate under the same CA and
# clients keep working. Needs only the openssl command (1.1.1 or 3.x).
# Keys are ECDSA P-256; the CA lasts 10 years, the coordinator's certificate
# 825 days.
set -eu

if [ $# -lt 1 ] || [ "$1" = "-h" ] || [ "$1" = "--help" ]; then
    sed -n '2,20p' "$0" | sed 's/^# \{0,1\}//'
    [ $# -ge 1 ] && exit 0
    exit 2
fi
command -v openssl >/dev/null 2>&1 || {
    echo "make-certs.sh: the openssl command is needed" >&2
    exit 1
}

# openssl's chatter only when it fails.
quiet() {
    if ! log=$("$@" 2>&1); then
        echo "$log" >&2
        echo "make-certs.sh: failed: $*" >&2
        exit 1
    fi
}

out=$1
shift
mkdir -p "$out"
umask 077

san="DNS:localhost,IP:127.0.0.1,IP:::1,DNS:coordinator"
for name in "$@"; do
    case "$name" in
        *[!0-9.]*)
            case "$name" in
                *:*) san="$san,IP:$name" ;;  # IPv6
                *) san="$san,DNS:$name" ;;
            esac
            ;;
        *) san="$san,IP:$name" ;;            # IPv4
    esac
done

if [ -f "$out/ca.pem" ] && [ -f "$out/ca.key" ]; then
    echo "reusing the CA in $out/ca.pem"
else
    quiet openssl req -x509 -new -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes \
        -keyout "$out/ca.key" -out "$out/ca.pem" -days 3650 -sha256 \
        -subj "/CN=Trevi farm CA" \
        -addext "basicConstraints=critical,CA:TRUE" \
        -addext "keyUsage=critical,keyCertSign,cRLSign"
fi

ext=$(mktemp)
csr=$(mktemp)
trap 'rm -f "$ext" "$csr"' EXIT
cat >"$ext" <<EOF
basicConstraints=critical,CA:FALSE
keyUsage=critical,digitalSignature,keyEncipherment
extendedKeyUsage=serverAuth
subjectAltName=$san
EOF
quiet openssl req -new -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes \
    -keyout "$out/coordinator.key" -out "$csr" -subj "/CN=trevi-coordinator"
quiet openssl x509 -req -in "$csr" -CA "$out/ca.pem" -CAkey "$out/ca.key" -CAcreateserial \
    -out "$out/coordinator.pem" -days 825 -sha256 -extfile "$ext"
rm -f "$out/ca.srl"
chmod 644 "$out/ca.pem" "$out/coordinator.pem"

echo "wrote $out/ca.pem, $out/ca.key, $out/coordinator.pem, $out/coordinator.key"
echo "the coordinator's certificate is for: $(echo "$san" | sed 's/DNS://g; s/IP://g; s/,/ /g')"
