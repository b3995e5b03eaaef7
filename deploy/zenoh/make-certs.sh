#!/bin/sh
# Makes the zenoh fabric's CA and one certificate per member with OpenSSL (Debian: openssl).
#
#   make-certs.sh DIR NAME[=SUBJECT_ALT_NAMES]...
#
# DIR gets ca.crt and ca.key (the plant's zenoh CA; keep ca.key off the gateways), and for each
# NAME NAME.crt and NAME.key: an EC P-256 key and a certificate whose common name is NAME,
# signed by the CA, valid for DAYS (default 825) days, for TLS servers and clients alike. The
# common name is what the router's access_control matches (`cert_common_names`): a gateway's
# certificate must be named as the gateway ([gateway] name), since only the certificate that
# names it may hold the liveliness token gw/<name>. A router's certificate must also carry the
# names clients connect to, e.g.
#
#   make-certs.sh /etc/gateway/zenoh router=DNS:zenoh-router.hall1,IP:10.1.0.1 cab1 cab2 hmi-1 historian
#
# An existing CA in DIR is reused (new members can be added later); an existing member's files
# are replaced. Key files are made mode 0600.
set -eu

if [ $# -lt 2 ]; then
    echo "usage: $0 DIR NAME[=SUBJECT_ALT_NAMES]..." >&2
    exit 64
fi
dir=$1
shift
days=${DAYS:-825}
mkdir -p "$dir"
umask 077

if [ ! -f "$dir/ca.key" ] || [ ! -f "$dir/ca.crt" ]; then
    openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes \
        -keyout "$dir/ca.key" -out "$dir/ca.crt" -days "$days" \
        -subj "/CN=zenoh fabric CA" \
        -addext "basicConstraints=critical,CA:TRUE" \
        -addext "keyUsage=critical,keyCertSign,cRLSign" 2>/dev/null
fi

for member in "$@"; do
    name=${member%%=*}
    san=
    if [ "$name" != "$member" ]; then
        san=${member#*=}
    fi
    case $name in
        '' | *[!A-Za-z0-9_.-]*)
            echo "$0: bad name '$name' (letters, digits, '.', '_', '-')" >&2
            exit 64
            ;;
    esac
    ext=$(mktemp)
    {
        echo "basicConstraints=critical,CA:FALSE"
        echo "keyUsage=critical,digitalSignature"
        echo "extendedKeyUsage=serverAuth,clientAuth"
        echo "subjectAltName=DNS:$name${san:+,$san}"
    } >"$ext"
    openssl req -new -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes \
        -keyout "$dir/$name.key" -out "$dir/$name.csr" -subj "/CN=$name" 2>/dev/null
    openssl x509 -req -in "$dir/$name.csr" -CA "$dir/ca.crt" -CAkey "$dir/ca.key" \
        -CAcreateserial -days "$days" -extfile "$ext" -out "$dir/$name.crt" 2>/dev/null
    rm -f "$ext" "$dir/$name.csr"
    chmod 0644 "$dir/$name.crt"
    echo "$dir/$name.crt: CN=$name"
done
chmod 0644 "$dir/ca.crt"
