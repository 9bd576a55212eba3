"""The project's module plug-ins (entry-point group ``clis.modules``): the paper's ``innate``,
``view`` and ``place`` (Sec. III-B..D), and ``wall``, an example of a module of one's own
(docs/modules.md)."""
