"""The one line for a failed https (TLS) handshake with a granule's server, in words of
what the server did (it speaks plain http; its certificate is not trusted)."""

from __future__ import annotations

__all__ = ["tls_failed", "tls_message"]


def tls_failed(exc: BaseException) -> bool:
    """True for a failed TLS (https) handshake or certificate check."""
    import ssl

    return isinstance(exc, ssl.SSLError) or "SSL" in type(exc).__name__ \
        or "Certificate" in type(exc).__name__


def tls_message(chain: list[BaseException], label: str) -> str:
    """The one line (naming ``label``) for a failed https handshake, in words of what the
    server did."""
    text = " ".join(str(e) for e in chain).lower()
    if "certificate" in text:
        return (f"{label}: the server's https certificate is not trusted (certificate "
                "verify failed); check the address, or install the certificate authority "
                "it uses")
    if "wrong_version" in text or "wrong version" in text or "record layer" in text:
        return (f"{label}: the server does not speak https (it answered the TLS handshake "
                "in plain http); use the http:// URL")
    return (f"{label}: the https (TLS) handshake with the server failed; check the address "
            "(http:// for a server without TLS)")
