"""A class graded on a Dask cluster that no student's code can reach.

A Dask scheduler runs whatever a connected client asks, on every worker (``Client.run``), as
the workers' user: a student's code that reaches the scheduler could patch the grader of the
whole class. Two lines hold it:

- **the student's code has no network**: ``grade-all --scheduler`` grades only where the
  student's process gets a network namespace of its own (loopback only): the student's view
  (bubblewrap), or, without it, as root, the separate user's own namespace
  (:data:`doorlab.pset.isolation.choice.OWN_NAMESPACES`). Before anything is graded a worker is
  asked how it would isolate (:func:`check_workers`): a cluster whose workers cannot is refused in
  one line, and every grading checks it again on its own worker (a grading there is an
  ``error`` row, never a grade);
- **the cluster speaks TLS and knows its clients**: a Dask scheduler runs what any connected
  client asks, so ``grade-all --scheduler`` grades only on one that speaks TLS and refuses a
  client without a key signed by the course's certificate authority (:func:`check_cluster`:
  a ``tcp://`` address is refused at once, a ``tls://`` one is tried without a key, which
  must fail); ``--insecure-cluster`` grades anyway, with a one-line warning.
  :func:`write_cluster_keys` (``doorlab pset cluster-keys DIR``) makes the course's
  certificate authority and a certificate and key for the scheduler, the workers and the
  grader (``dask scheduler --tls-ca-file DIR/ca.pem --tls-cert DIR/scheduler.pem --tls-key
  DIR/scheduler.key``, the workers likewise, ``grade-all --cluster-keys DIR``);
  :func:`local_cluster` starts one on this machine with a certificate made in memory for it
  (``distributed``'s ``Security.temporary()``). The workers need not run as root where
  bubblewrap can make its namespaces and a delegated cgroup serves
  (:mod:`doorlab.pset.isolation.cgroups`).
"""

from __future__ import annotations

import contextlib
import datetime
import os
import socket
import ssl
import urllib.parse
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from doorlab.errors import ConfigError, OutputError

CHECK_TIMEOUT_S = 120.0
"""How long a worker may take to say how it would isolate [s] (it builds the view once)."""


def worker_isolation(policy: str) -> dict:
    """On a worker: how its gradings would isolate the student's code (``mode``,
    ``network_isolated``, ``reason``), or why none can (``error``)."""
    import tempfile
    from pathlib import Path

    from doorlab.pset.isolation.choice import IsolationError, prepare

    with tempfile.TemporaryDirectory(prefix="doorlab_probe_") as tmp:
        try:
            isolation = prepare(Path(tmp), policy)
        except (IsolationError, OSError) as e:
            return {"error": str(e)}
    return {
        "mode": isolation.mode,
        "network_isolated": isolation.network_isolated,
        "reason": isolation.reason,
    }


def check_workers(executor, policy: str) -> dict:
    """Asks a worker of ``executor`` how it would isolate; returns its answer.

    Raises:
        ConfigError: The worker's gradings would let the student's code reach the network
            (so the cluster), or it cannot isolate it at all (one line).
    """
    from doorlab.runtime.inputs import quote_text

    future = executor.submit(worker_isolation, policy)
    try:
        facts = future.result(timeout=CHECK_TIMEOUT_S)
    except Exception as e:  # noqa: BLE001 - the worker's failure, in one line
        raise ConfigError(
            f"--scheduler: a worker could not say how it isolates the student's code "
            f"({type(e).__name__}: {quote_text(str(e))})"
        ) from None
    if "error" in facts:
        raise ConfigError(f"--scheduler: a worker cannot grade: {quote_text(facts['error'])}")
    if not facts.get("network_isolated"):
        raise ConfigError(
            "--scheduler: the cluster's workers would run the student's code without a "
            f"network namespace ({quote_text(facts.get('reason') or facts.get('mode'))}), "
            "so it could reach the scheduler and run code on every worker; install "
            "bubblewrap on the workers (or run them as root: the separate user then gets a "
            "namespace of its own)"
        )
    return facts


@dataclass
class LocalCluster:
    """A Dask cluster on this machine's loopback, TLS only (see :func:`local_cluster`).

    Attributes:
        address: The scheduler's ``tls://`` address.
        security: The ``distributed.Security`` a client needs to connect (its key is in
            this process's memory only).
    """

    address: str
    security: object


@contextlib.contextmanager
def local_cluster(workers: int = 2) -> Iterator[LocalCluster]:
    """A ``distributed.LocalCluster`` of ``workers`` processes (one thread each) on
    loopback whose comms are TLS with a certificate made for it, for the ``with`` block.

    Raises:
        ConfigError: ``distributed`` or ``cryptography`` is missing (the extra ``sweep``).
    """
    try:
        from distributed import LocalCluster as DaskCluster
        from distributed import Security

        security = Security.temporary()
    except ImportError as e:
        raise ConfigError(
            f'a TLS cluster needs distributed and cryptography (pip install "doorlab[sweep]"): {e}'
        ) from None
    with DaskCluster(
        n_workers=workers,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        protocol="tls://",
        security=security,
        dashboard_address=None,
        # The scheduler's HTTP routes (health, metrics) on a free loopback port: Dask's
        # default, 8787, is where a course's own dashboard usually is.
        scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
        silence_logs=40,
    ) as cluster:
        yield LocalCluster(cluster.scheduler_address, security)


# The course's keys -------------------------------------------------------------------------

ROLES = ("scheduler", "worker", "client")
"""Who gets a certificate and key: the scheduler, the workers, the grader (Dask's client)."""
KEY_DAYS = 365
"""How long the certificates are valid [days] (a course's year)."""
INSECURE_CLUSTER_WARNING = (
    "--insecure-cluster: the scheduler at {address} {why}: whoever reaches it can run code on "
    "every worker and change every grade of this class"
)
"""The one line ``grade-all --insecure-cluster`` prints before it grades."""


def _crypto():
    try:
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes, serialization
        from cryptography.hazmat.primitives.asymmetric import ec
        from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID
    except ImportError as e:
        raise ConfigError(
            f'making the cluster\'s keys needs cryptography (pip install "doorlab[sweep]"): {e}'
        ) from None
    return x509, hashes, serialization, ec, ExtendedKeyUsageOID, NameOID


def _san(x509, hosts: Sequence[str]):
    import ipaddress

    names = []
    for host in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    return x509.SubjectAlternativeName(names)


def write_cluster_keys(
    out: Path, hosts: Sequence[str] = ("localhost", "127.0.0.1"), *, force: bool = False
) -> Path:
    """Writes a course's cluster keys into the new folder ``out`` (mode 0700): its own
    certificate authority (``ca.pem``, every role's ``--tls-ca-file``; ``ca.key``, needed only
    to sign more: keep it offline) and, signed by it, a certificate and key for each of
    :data:`ROLES` (``scheduler.pem`` and ``scheduler.key``...; keys 0600), valid
    :data:`KEY_DAYS` days for ``hosts`` (names or addresses; Dask checks the authority, not
    the name). Returns ``out``.

    Raises:
        ConfigError: ``cryptography`` is missing. OutputError: ``out`` may not be written.
    """
    from doorlab.runtime.folders import staged_output

    x509, hashes, serialization, ec, usage, oid = _crypto()
    now = datetime.datetime.now(datetime.timezone.utc)
    until = now + datetime.timedelta(days=KEY_DAYS)

    def name(common: str):
        return x509.Name([x509.NameAttribute(oid.COMMON_NAME, common)])

    def pem_key(key) -> bytes:
        return key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = (
        x509.CertificateBuilder()
        .subject_name(name("doorlab course cluster CA"))
        .issuer_name(name("doorlab course cluster CA"))
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now)
        .not_valid_after(until)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(False, False, False, False, False, True, True, False, False), True
        )
        .sign(ca_key, hashes.SHA256())
    )
    files = {"ca.pem": ca.public_bytes(serialization.Encoding.PEM), "ca.key": pem_key(ca_key)}
    for role in ROLES:
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (
            x509.CertificateBuilder()
            .subject_name(name(f"doorlab {role}"))
            .issuer_name(ca.subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now)
            .not_valid_after(until)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(
                x509.ExtendedKeyUsage([usage.SERVER_AUTH, usage.CLIENT_AUTH]), critical=False
            )
            .add_extension(_san(x509, hosts), critical=False)
            .sign(ca_key, hashes.SHA256())
        )
        files[f"{role}.pem"] = cert.public_bytes(serialization.Encoding.PEM)
        files[f"{role}.key"] = pem_key(key)
    with staged_output(out, force=force) as staging:
        os.chmod(staging, 0o700)
        for file_name, data in files.items():
            mode = 0o600 if file_name.endswith(".key") else 0o644
            fd = os.open(staging / file_name, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
            with os.fdopen(fd, "wb") as f:
                f.write(data)
    return Path(out)


def cluster_security(folder: Path):
    """The ``distributed.Security`` of the grader's client from a :func:`write_cluster_keys`
    folder (its ``ca.pem``, ``client.pem``, ``client.key``).

    Raises:
        OutputError: A file is missing. ConfigError: ``distributed`` is missing.
    """
    folder = Path(folder)
    paths = {n: folder / f for n, f in (("ca", "ca.pem"), ("cert", "client.pem"))}
    paths["key"] = folder / "client.key"
    for path in paths.values():
        if not path.is_file():
            raise OutputError(
                f"--cluster-keys {str(folder)!r} holds no {path.name} (doorlab pset "
                "cluster-keys DIR writes the cluster's keys)"
            )
    try:
        from distributed import Security
    except ImportError as e:
        raise ConfigError(
            f'--cluster-keys needs distributed (pip install "doorlab[sweep]"): {e}'
        ) from None
    return Security(
        tls_ca_file=str(paths["ca"]),
        tls_client_cert=str(paths["cert"]),
        tls_client_key=str(paths["key"]),
        require_encryption=True,
    )


# A cluster the grader may trust ------------------------------------------------------------

ANONYMOUS_TIMEOUT_S = 10.0
"""How long the try without a key may take [s]."""
_REFUSED_REASONS = ("CERTIFICATE_REQUIRED", "HANDSHAKE_FAILURE", "PEER_DID_NOT_RETURN")
"""What a TLS server that requires a client's certificate answers one without (OpenSSL's
reasons: TLS 1.3's alert, TLS 1.2's)."""


def accepts_anonymous(address: str, ca_file: str | None, timeout: float = ANONYMOUS_TIMEOUT_S):
    """Whether the TLS server at ``address`` lets a client without a certificate talk to it
    (True), refuses it (False: it asks every client for a key its authority signed), or
    ``None``: it cannot be told (an error other than that refusal).

    The try verifies the server against ``ca_file`` when given (not the name: Dask's
    certificates name no host), completes the handshake without a certificate and waits
    for the server's first word: TLS 1.3 refuses there (``certificate required``), TLS 1.2 in
    the handshake; a server that accepts says its part of Dask's handshake, or waits.
    """
    parts = urllib.parse.urlsplit(address)
    context = ssl.create_default_context(
        cafile=ca_file if ca_file and "\n" not in ca_file else None
    )
    if ca_file and "\n" in ca_file:
        context.load_verify_locations(cadata=ca_file)
    context.check_hostname = False
    if not ca_file:
        context.verify_mode = ssl.CERT_NONE
    try:
        with socket.create_connection((parts.hostname, parts.port), timeout=timeout) as raw:
            with context.wrap_socket(raw, server_hostname=parts.hostname) as tls:
                tls.settimeout(min(timeout, 3.0))
                try:
                    tls.recv(1)
                except TimeoutError:
                    return True  # connected, and the server waits for what it would serve
                return True  # it said something (or closed cleanly): no key asked
    except ssl.SSLError as e:
        text = f"{e.reason} {e}".upper()
        if any(reason in text for reason in _REFUSED_REASONS):
            return False
        return None
    except OSError:
        return None


def plain(address: str) -> str | None:
    """Why a scheduler at ``address`` cannot be trusted from its address alone (not TLS), or
    None."""
    scheme = urllib.parse.urlsplit(address).scheme
    if scheme in ("tls", "wss"):
        return None
    return f"speaks plain {scheme}:// (no TLS, no client keys)"


def refuse(address: str, why: str) -> ConfigError:
    """The one line refusing a scheduler that cannot be trusted."""
    return ConfigError(
        f"--scheduler: the scheduler at {address} {why}: whoever reaches it could run code on "
        "every worker and change every grade; start the cluster with TLS and the course's "
        "keys (doorlab pset cluster-keys DIR; docs/guides/teaching.md) and pass --cluster-keys "
        "DIR, or --insecure-cluster to grade there anyway"
    )


def check_cluster(address: str, security, *, insecure: bool) -> str | None:
    """Checks that grading on the scheduler at ``address`` is safe: TLS, and no client
    without a key of its authority gets in (:func:`accepts_anonymous`). Returns the warning
    to print with ``insecure`` where it is not, else None.

    Raises:
        ConfigError: Without ``insecure``, a scheduler that is not TLS or lets a client in
            without a key (one line naming ``--insecure-cluster`` and the guide's keys).
    """
    why = plain(address)
    if why is None:
        ca = getattr(security, "tls_ca_file", None) if security is not None else None
        if accepts_anonymous(address, ca) is not False:
            why = "speaks TLS but let a client without a key signed by its authority connect"
    if why is None:
        return None
    if insecure:
        return INSECURE_CLUSTER_WARNING.format(address=address, why=why)
    raise refuse(address, why)
