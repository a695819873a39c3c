#!/usr/bin/env bash
# Make a private CA and certificates for Zenoh TLS (routers and clients), with openssl.
#
#   deploy/tls/make-certs.sh OUTDIR NAME[=SAN,SAN...] [NAME[=SAN,...] ...]
#
# OUTDIR gets ca.pem + ca.key (made once, reused afterwards) and, for every NAME, NAME.pem + NAME.key:
# a certificate with CN=NAME signed by the CA, usable both as a TLS server (a router listening) and as a
# TLS client (a router connecting to another router, or a client with mutual TLS).  Its subjectAltName
# always holds DNS:NAME, plus the SANs given after '=' (IP:10.77.0.1, DNS:broker.lab, ...): a client
# with verify_name_on_connect checks the address it connects to against these, so a router certificate
# needs the IP or DNS name clients use (add IP:127.0.0.1,DNS:localhost for local clients over TLS).
# The CN is what an access-control subject matches (`cert_common_names`).
#
# An existing NAME.pem is kept (delete it, or set FORCE=1, to remake it).  DAYS (default 825) sets the
# validity.  Keys are written 0600 into OUTDIR: keep OUTDIR out of version control, and copy to each
# machine only the CA certificate (ca.pem, never ca.key) and that machine's own NAME.pem/NAME.key.
# `uwsimnet deploy certs INVENTORY` prints the command for an inventory.
set -euo pipefail

die() { echo "make-certs: $*" >&2; exit 2; }
command -v openssl >/dev/null 2>&1 || die "openssl not found on PATH (apt-get install openssl)"
[ $# -ge 1 ] || die "usage: $0 OUTDIR NAME[=SAN,SAN...] ..."
case "$1" in -h|--help) sed -n '2,19p' "$0" | sed 's/^# \{0,1\}//'; exit 0;; esac

out=$1; shift
days=${DAYS:-825}
umask 077
mkdir -p "$out"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

newkey() { openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null; }

if [ ! -s "$out/ca.pem" ] || [ ! -s "$out/ca.key" ]; then
    newkey "$out/ca.key"
    cat > "$tmp/ca.cnf" <<CNF
[req]
distinguished_name = dn
prompt = no
x509_extensions = v3_ca
[dn]
CN = uwsimnet-ca
[v3_ca]
basicConstraints = critical, CA:TRUE
keyUsage = critical, keyCertSign, cRLSign
subjectKeyIdentifier = hash
CNF
    openssl req -new -x509 -config "$tmp/ca.cnf" -key "$out/ca.key" -days "$days" -sha256 \
        -out "$out/ca.pem" 2>/dev/null || die "cannot make the CA"
    echo "made CA $out/ca.pem"
fi

for spec in "$@"; do
    name=${spec%%=*}
    sans="DNS:$name"
    if [ "$spec" != "$name" ] && [ -n "${spec#*=}" ]; then sans="$sans,${spec#*=}"; fi
    [[ "$name" =~ ^[A-Za-z0-9][A-Za-z0-9._-]*$ ]] || die "bad name '$name' (letters, digits, . _ -)"
    [ "$name" != ca ] || die "'ca' is the CA's own file name"
    if [ -s "$out/$name.pem" ] && [ -s "$out/$name.key" ] && [ "${FORCE:-0}" != 1 ]; then
        echo "kept $out/$name.pem"
        continue
    fi
    newkey "$out/$name.key"
    cat > "$tmp/$name.cnf" <<CNF
[req]
distinguished_name = dn
prompt = no
[dn]
CN = $name
[ext]
basicConstraints = critical, CA:FALSE
keyUsage = critical, digitalSignature, keyEncipherment
extendedKeyUsage = serverAuth, clientAuth
subjectAltName = $sans
subjectKeyIdentifier = hash
authorityKeyIdentifier = keyid
CNF
    openssl req -new -config "$tmp/$name.cnf" -key "$out/$name.key" -out "$tmp/$name.csr" 2>/dev/null \
        || die "cannot make the request for $name"
    openssl x509 -req -in "$tmp/$name.csr" -CA "$out/ca.pem" -CAkey "$out/ca.key" -CAcreateserial \
        -CAserial "$tmp/ca.srl" -days "$days" -sha256 -extfile "$tmp/$name.cnf" -extensions ext \
        -out "$out/$name.pem" 2>/dev/null || die "cannot sign the certificate of $name (SANs: $sans)"
    echo "made $out/$name.pem (CN=$name, $sans)"
done
