"""`foldcell security init DIR` and `foldcell security show DIR`: the cell's CA and certificates."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from drivers.wire.security import (
    CA_NAME,
    CA_PRIVATE,
    create_security,
    default_hosts,
    identity,
    load_security_config,
)
from tools.common import UsageError, path_argument, print_json


def cmd_init(args: argparse.Namespace) -> int:
    # the names given are added to this machine's and loopback's, which the cell's own processes dial
    hosts = list(dict.fromkeys([*default_hosts(), *(args.host or [])]))
    written = create_security(args.directory, hosts, force=args.force)
    roles = list(load_security_config().roles)
    ca_key = Path(args.directory) / CA_PRIVATE / f"{CA_NAME}.key"
    if args.json:
        print_json({"directory": str(args.directory), "roles": roles, "hosts": hosts,
                    "files": [str(path) for path in written]})
    else:
        print(f"{args.directory}: a CA and one directory per role, {', '.join(roles)} (valid for "
              f"{', '.join(hosts)})")
        print(f"start each process with its role's directory, --security {Path(args.directory) / '<role>'} "
              "(or FOLDCELL_SECURITY), and copy to each machine only the directories of the roles it runs")
    print(f"foldcell: warning: {ca_key} signs certificates of any role: move it off the cell's machines",
          file=sys.stderr)
    return 0


def cmd_show(args: argparse.Namespace) -> int:
    from cryptography import x509

    if not args.directory.is_dir():
        raise UsageError(f"DIR: {args.directory} is not a directory (make one with `foldcell security init "
                         "DIR`)")
    rows = []
    for role, rights in load_security_config().roles.items():
        files = identity(args.directory / role, role, "DIR")
        certificate = x509.load_pem_x509_certificate(files.certificate.read_bytes())
        rows.append({"role": role, "certificate": str(files.certificate),
                     "valid_until": certificate.not_valid_after_utc.isoformat(),
                     "publishes": list(rights.publishes), "serves": list(rights.serves),
                     "calls": list(rights.calls)})
    if args.json:
        print_json(rows)
        return 0
    for row in rows:
        print(f"{row['role']:11} valid until {row['valid_until'][:10]}  "
              f"publishes {', '.join(row['publishes']) or '-'}; serves {', '.join(row['serves']) or '-'}; "
              f"calls {', '.join(row['calls']) or '-'}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    security = subparsers.add_parser(
        "security", help="the cell's CA and per-role certificates (mutual TLS, access control)",
        description="Make and check the certificates a secured cell runs with (--security DIR/<role> "
                    "on every process). Each role's rights are config/security.yaml's.")
    group = security.add_subparsers(dest="security_command", required=True, metavar="COMMAND")
    init = group.add_parser("init", help="make a CA and one certificate per role in DIR",
                            description="Writes DIR/<role>/ (ca.pem, <role>.pem, <role>.key) for every "
                                        "role of config/security.yaml, and the CA's key in "
                                        f"DIR/{CA_PRIVATE}/ (directories and keys readable by the owner "
                                        "only). Give each process its role's directory only.")
    init.add_argument("directory", metavar="DIR", type=path_argument, help="where the CA and certificates go")
    init.add_argument("--host", action="append", metavar="NAME",
                      help="a further host name or address the processes listen on, repeatable; the "
                           f"certificates always name {', '.join(default_hosts())}")
    init.add_argument("--force", action="store_true", help="replace a CA already in DIR")
    init.add_argument("--json", action="store_true", help="print what was written as JSON")
    init.set_defaults(func=cmd_init)
    show = group.add_parser("show", help="check DIR's certificates and list each role's rights",
                            description="Checks every role's certificate in DIR against its CA and "
                                        "prints the role's rights; fails naming the first bad file.")
    show.add_argument("directory", metavar="DIR", type=path_argument,
                      help="the top directory `security init` made")
    show.add_argument("--json", action="store_true", help="one JSON object per role")
    show.set_defaults(func=cmd_show)
