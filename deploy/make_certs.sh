#!/usr/bin/env bash
# Makes a local certificate authority, a server certificate and a client certificate (for mutual
# TLS), plus a bearer-token file with one random token per role, for the tests and the demo:
#
#   deploy/make_certs.sh OUT_DIR [SERVER_NAME ...]
#
# OUT_DIR/ca.pem            the CA certificate (clients: --tls_ca; server with mTLS: --tls_client_ca)
# OUT_DIR/server.pem, server.key   for exoview_server --tls_cert / --tls_key; SAN: localhost,
#                                  127.0.0.1, ::1 and every SERVER_NAME given
# OUT_DIR/client.pem, client.key   for clients' --tls_cert / --tls_key (mutual TLS)
# OUT_DIR/tokens.txt        exoview_server --auth_tokens_file: "ROLE TOKEN NAME" lines
# OUT_DIR/<role>.token      the token of each role alone (clients' --token_file)
#
# Keys are EC P-256, certificates valid 30 days. Nothing here is for production: a real
# deployment uses its own CA and secret store (docs/security.md).
set -euo pipefail
out="${1:?usage: deploy/make_certs.sh OUT_DIR [SERVER_NAME ...]}"
shift
command -v openssl >/dev/null || { echo "make_certs: openssl is not installed" >&2; exit 1; }
mkdir -p "$out"
cd "$out"
umask 077

san="DNS:localhost,IP:127.0.0.1,IP:::1"
for name in "$@"; do
  if [[ "$name" =~ ^[0-9.]+$ || "$name" == *:* ]]; then san+=",IP:$name"; else san+=",DNS:$name"; fi
done

key() { openssl ecparam -name prime256v1 -genkey -noout -out "$1" 2>/dev/null; }

key ca.key
openssl req -x509 -new -key ca.key -sha256 -days 30 -subj "/CN=Exoview local CA" \
  -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" \
  -out ca.pem 2>/dev/null

sign() {  # sign NAME CN EXTENSIONS
  key "$1.key"
  openssl req -new -key "$1.key" -subj "/CN=$2" -out "$1.csr" 2>/dev/null
  printf '%s\n' "$3" > "$1.ext"
  openssl x509 -req -in "$1.csr" -CA ca.pem -CAkey ca.key -CAcreateserial -days 30 -sha256 \
    -extfile "$1.ext" -out "$1.pem" 2>/dev/null
  rm -f "$1.csr" "$1.ext"
}
sign server "exoview-server" "subjectAltName=$san
extendedKeyUsage=serverAuth
keyUsage=critical,digitalSignature"
sign client "exoview-client" "extendedKeyUsage=clientAuth
keyUsage=critical,digitalSignature"
rm -f ca.srl

: > tokens.txt
for role in uploader viewer operator admin; do
  tok="$(openssl rand -hex 24)"
  printf '%s\n' "$tok" > "$role.token"
  printf '%s %s %s-1\n' "$role" "$tok" "$role" >> tokens.txt
done
chmod 600 ./*.key tokens.txt ./*.token
chmod 644 ca.pem server.pem client.pem
echo "make_certs: CA, server and client certificates and role tokens in $PWD" >&2
