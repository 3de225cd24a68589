#!/bin/sh
# Create the certificates of one uwbnet network: a private certificate authority (CA) and one
# key/certificate pair per host, signed by it. Zenoh's mutual TLS admits only processes that
# present a certificate of this CA; the access-control rules in deploy/zenoh/ match the
# certificates' common names (CN).
#
#   deploy/make-certs.sh DIR NAME [NAME ...]
#
# DIR must be outside the repository (the keys are secrets); it is created with mode 700.
# Each NAME becomes DIR/NAME.key and DIR/NAME.pem with CN=NAME and subjectAltName DNS:NAME
# (plus IP:ADDR when NAME is written NAME@ADDR, e.g. fusion@10.0.0.1). Existing CA files are
# reused, so hosts can be added later.
set -eu
if [ $# -lt 2 ]; then
    echo "usage: $0 DIR NAME[@IP] [NAME[@IP] ...]" >&2
    exit 2
fi
dir=$1; shift
repo=$(cd "$(dirname "$0")/.." && pwd)
mkdir -p "$dir"
case "$(cd "$dir" && pwd)/" in
    "$repo"/*)
        rmdir "$dir" 2>/dev/null || true
        echo "$0: refusing to write keys inside the repository ($dir)" >&2; exit 2;;
esac
umask 077
chmod 700 "$dir"
days=${UWBNET_CERT_DAYS:-825}
if [ ! -f "$dir/ca.key" ]; then
    openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days "$days" \
        -subj "/CN=uwbnet-ca" -keyout "$dir/ca.key" -out "$dir/ca.pem" 2>/dev/null
fi
for spec in "$@"; do
    name=${spec%@*}
    san="DNS:$name,DNS:localhost,IP:127.0.0.1"
    [ "$spec" != "$name" ] && san="$san,IP:${spec#*@}"
    openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -subj "/CN=$name" \
        -keyout "$dir/$name.key" -out "$dir/$name.csr" 2>/dev/null
    printf 'subjectAltName=%s\nextendedKeyUsage=serverAuth,clientAuth\n' "$san" > "$dir/$name.ext"
    openssl x509 -req -in "$dir/$name.csr" -CA "$dir/ca.pem" -CAkey "$dir/ca.key" \
        -CAcreateserial -days "$days" -extfile "$dir/$name.ext" -out "$dir/$name.pem" 2>/dev/null
    rm -f "$dir/$name.csr" "$dir/$name.ext"
    echo "$dir/$name.pem"
done
