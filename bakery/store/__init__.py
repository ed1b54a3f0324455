"""The HDF5 probe store (only this package imports h5py). Format: ``schemas/store-v1.md``."""

from bakery.store.format import FORMAT_NAME, FORMAT_VERSION, StoreContents, migrate_store, read_store, write_store

__all__ = ["FORMAT_NAME", "FORMAT_VERSION", "StoreContents", "migrate_store", "read_store", "write_store"]
