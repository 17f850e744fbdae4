"""sessions: the anchor's WMM date, accuracy and source; Sensor Logger links: time of the last push

A session's anchor is its latitude_deg/longitude_deg/altitude_m (revision 0001) plus the date the World Magnetic
Model is evaluated at (NULL: the session's creation date), the anchor's horizontal accuracy [m] (a location
fix's; NULL when given by hand) and where it came from ("user", "location", "gnss", "replay"). A Sensor Logger
link keeps the time of its last push, from which an idle session is closed.

Revision ID: 0006
Revises: 0005
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # plain ADD COLUMNs (no table rebuild on SQLite: the sessions table keeps its AUTOINCREMENT of revision 0005)
    op.add_column("sessions", sa.Column("anchor_date", sa.Date(), nullable=True))
    op.add_column("sessions", sa.Column("anchor_accuracy_m", sa.Float(), nullable=True))
    op.add_column("sessions", sa.Column("anchor_source", sa.String(length=20), nullable=True))
    op.add_column("sensorlogger_links", sa.Column("last_push_at", sa.DateTime(timezone=True), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("sensorlogger_links") as b:
        b.drop_column("last_push_at")
    with op.batch_alter_table("sessions", recreate="always", table_kwargs={"sqlite_autoincrement": True}) as b:
        b.drop_column("anchor_source")
        b.drop_column("anchor_accuracy_m")
        b.drop_column("anchor_date")
