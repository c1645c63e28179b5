"""``python -m tools.flight.keygen [--passphrase] FILE``: create a MAVLink 2 signing key file (64 hex digits, mode
0600).

Give the same file to every process of a flight with ``--signing-key FILE`` (the launcher makes one per flight by
itself).  The file must not exist yet; the key is never printed.

Without ``--passphrase`` the key is 32 random bytes.  With ``--passphrase`` it is SHA-256 of a passphrase, the key
MAVProxy derives from the same passphrase (``signing setup PASSPHRASE`` or ``signing key PASSPHRASE``, module
``mavproxy_signing.passphrase_to_key``: ``hashlib.sha256(passphrase.encode('ascii')).digest()``), and the key
QGroundControl versions with a "MAVLink 2 signing key" text setting derive from that text
(``QCryptographicHash::hash(key, Sha256)`` in ``MAVLinkSigning::initSigning``).  The passphrase is read from
standard input (its first line, without the line ending), or prompted for twice without echo on a terminal;
never from the command line, where it would stay in the shell history and show in ``ps``.  It must be at least
8 characters of printable ASCII without spaces (MAVProxy encodes it as ASCII and takes it as one word of its
command line).  A passphrase key is only as strong as the passphrase: anyone who records one signed packet can
try passphrases offline, so use a long random one, or a random key file (no ``--passphrase``) where the ground
station takes a raw key.

In MAVProxy prefer ``signing key PASSPHRASE`` (or a ``~/.mavproxy/signing.keys`` line ``HOST:PORT PASSPHRASE``,
which keeps the passphrase off MAVProxy's command line too) to ``signing setup``, which first sends the key itself,
in a SETUP_SIGNING message over the link (unsigned unless signing was already on; this autopilot takes no key
from a link and rejects it), and add ``set allow_unsigned 0``:
by default MAVProxy also accepts packets whose signature is wrong.  Give each ground station its own component
id (MAVProxy ``--source-component``): stations with the same ids share one timestamp stream and lose packets as
``replay``.
"""

from __future__ import annotations

import getpass
import hashlib
import os
import sys

from autopilot.shared.cli import OneLineArgumentParser, output_file_problem
from autopilot.shared.signing import KeyFileError, write_key

PROG = "python -m tools.flight.keygen"
MIN_PASSPHRASE = 8  # characters (QGroundControl's minimum for its passphrase keys too)


class PassphraseError(ValueError):
    """A passphrase that cannot be used (one-line message)."""


def passphrase_key(passphrase: str) -> bytes:
    """The 32-byte key of a passphrase: SHA-256 of its ASCII bytes (MAVProxy's ``passphrase_to_key``);
    :class:`PassphraseError` if it is empty, short, not printable ASCII or contains whitespace."""
    if not passphrase:
        raise PassphraseError("empty passphrase")
    if not all(33 <= ord(c) <= 126 for c in passphrase):
        raise PassphraseError(
            "the passphrase must be printable ASCII without spaces (MAVProxy takes it as one ASCII word)"
        )
    if len(passphrase) < MIN_PASSPHRASE:
        raise PassphraseError(f"passphrase of {len(passphrase)} characters: at least {MIN_PASSPHRASE} are needed")
    return hashlib.sha256(passphrase.encode("ascii")).digest()


def read_passphrase(stdin=None) -> str:
    """The passphrase: prompted twice without echo if standard input is a terminal, else its first line."""
    stdin = sys.stdin if stdin is None else stdin
    if stdin is None:
        raise PassphraseError("no standard input to read the passphrase from")
    if stdin.isatty():
        first = getpass.getpass("passphrase: ")
        if getpass.getpass("passphrase again: ") != first:
            raise PassphraseError("the two passphrases differ")
        return first
    line = stdin.readline()
    return line[:-1].removesuffix("\r") if line.endswith("\n") else line


def main(argv=None) -> int:
    p = OneLineArgumentParser(
        prog=PROG,
        description=__doc__.split("\n\n")[0],
        epilog="--passphrase: the key is SHA-256 of a passphrase read from standard input (or prompted for "
        "without echo), the key MAVProxy's 'signing setup PASSPHRASE' uses; never give it on the command line.",
    )
    p.add_argument("file", metavar="FILE", help="the key file to create (must not exist)")
    p.add_argument(
        "--passphrase",
        action="store_true",
        help="derive the key from a passphrase (SHA-256, as MAVProxy's 'signing setup') read from standard input "
        "or prompted for without echo, instead of 32 random bytes",
    )
    args = p.parse_args(argv)
    if os.path.lexists(args.file):  # before asking for a passphrase (write_key checks again, atomically)
        p.error(f"{args.file} exists: remove it first or choose another name")
    problem = output_file_problem(args.file)  # an unwritable place: before asking for a passphrase too
    if problem:
        p.error(problem)
    key = None
    if args.passphrase:
        try:
            key = passphrase_key(read_passphrase())
        except (PassphraseError, EOFError, KeyboardInterrupt) as exc:
            p.error(str(exc) or "no passphrase")
    try:
        write_key(args.file, key)
    except FileExistsError:
        p.error(f"{args.file} exists: remove it first or choose another name")
    except (OSError, KeyFileError) as exc:  # a bad FILE, as every other error of this command: exit 2
        p.error(f"{args.file}: {getattr(exc, 'strerror', None) or exc}")
    how = " (SHA-256 of the passphrase, as MAVProxy's signing setup)" if args.passphrase else ""
    print(f"signing key written to {args.file} (mode 0600){how}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
