"""The service layer, one module per aggregate: what a route asks of the service.

- ``configs``: each study's immutable configuration, parsed once per process;
- ``studies``: creating a study (the checks the schema cannot make);
- ``trials``: proposing trials (an owner's ask, or one for a worker's lease);
- ``jobs``: leasing work to workers;
- ``transfer``: which evaluated design a leased job's controller starts from;
- ``budget``: an ask's memory budget.

Routes validate and call one function here or in a module of ``adservice.repository``; these
functions own their transactions (``Database.read``/``Database.write``, the one place that
commits) and never see HTTP.
"""
