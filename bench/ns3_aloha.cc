// ns-3 UAN side of bench/bench_ns3_aloha.py: the reference pure-ALOHA scenario
// (uwsimnet_zenoh/experiments/aloha.py, ../shared/notes/ns3-reference.md).
//
// A sink at the origin, N sensors on a 500 m circle (z = 0); one FSK mode at 1000 bps (22 kHz, 4 kHz
// band), 190 dB tx power, ideal propagation (no loss, delay = d / 1500 m/s), default noise; UanMacAloha
// (no ACK, no retry, no queue: a packet offered while its sensor transmits is dropped); 37-byte payloads
// (+3 bytes of UanHeaderCommon = 40 bytes = 0.32 s on air); Poisson arrivals of G / (N T) per sensor.
//
// usage: ns3_aloha N G DURATION SEED   -> prints "offered sent received wall_s"
#include "ns3/core-module.h"
#include "ns3/mobility-module.h"
#include "ns3/network-module.h"
#include "ns3/uan-module.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>

using namespace ns3;

static uint64_t g_offered = 0, g_sent = 0, g_received = 0;

static bool
SinkRx(Ptr<NetDevice>, Ptr<const Packet>, uint16_t, const Address&)
{
    ++g_received;
    return true;
}

struct Source
{
    Ptr<NetDevice> dev;
    Address sink;
    Ptr<ExponentialRandomVariable> gap;
    double stop;

    void Fire()
    {
        ++g_offered;
        if (dev->Send(Create<Packet>(37), sink, 0))
        {
            ++g_sent;
        }
        double next = Simulator::Now().GetSeconds() + gap->GetValue();
        if (next < stop)
        {
            Simulator::Schedule(Seconds(next) - Simulator::Now(), &Source::Fire, this);
        }
    }
};

int
main(int argc, char** argv)
{
    if (argc != 5)
    {
        std::fprintf(stderr, "usage: %s N G DURATION SEED\n", argv[0]);
        return 2;
    }
    const uint32_t n = std::atoi(argv[1]);
    const double load = std::atof(argv[2]);
    const double duration = std::atof(argv[3]);
    RngSeedManager::SetSeed(1);
    RngSeedManager::SetRun(std::atoi(argv[4]));
    const double frameTime = 40 * 8 / 1000.0;

    UanModesList modes;
    modes.AppendMode(UanTxModeFactory::CreateMode(UanTxMode::FSK, 1000, 1000, 22000, 4000, 2, "FSK"));
    UanHelper uan;
    uan.SetMac("ns3::UanMacAloha");
    uan.SetPhy("ns3::UanPhyGen",
               "PerModel", PointerValue(CreateObject<UanPhyPerGenDefault>()),
               "SinrModel", PointerValue(CreateObject<UanPhyCalcSinrDefault>()),
               "SupportedModes", UanModesListValue(modes));
    Ptr<UanChannel> channel = CreateObject<UanChannel>();
    channel->SetPropagationModel(CreateObject<UanPropModelIdeal>());
    channel->SetNoiseModel(CreateObject<UanNoiseModelDefault>());

    NodeContainer nodes;
    nodes.Create(n + 1);
    Ptr<ListPositionAllocator> pos = CreateObject<ListPositionAllocator>();
    pos->Add(Vector(0, 0, 0));
    for (uint32_t i = 0; i < n; ++i)
    {
        double a = 2 * M_PI * i / n;
        pos->Add(Vector(500 * std::cos(a), 500 * std::sin(a), 0));
    }
    MobilityHelper mobility;
    mobility.SetPositionAllocator(pos);
    mobility.SetMobilityModel("ns3::ConstantPositionMobilityModel");
    mobility.Install(nodes);
    NetDeviceContainer devs = uan.Install(nodes, channel);
    devs.Get(0)->SetReceiveCallback(MakeCallback(&SinkRx));

    std::vector<Source> sources(n);
    for (uint32_t i = 0; i < n; ++i)
    {
        Source& s = sources[i];
        s.dev = devs.Get(i + 1);
        s.sink = devs.Get(0)->GetAddress();
        s.gap = CreateObject<ExponentialRandomVariable>();
        s.gap->SetAttribute("Mean", DoubleValue(n * frameTime / load));
        s.stop = duration;
        double first = s.gap->GetValue();
        if (first < duration)
        {
            Simulator::Schedule(Seconds(first), &Source::Fire, &s);
        }
    }
    auto t0 = std::chrono::steady_clock::now();
    Simulator::Stop(Seconds(duration));
    Simulator::Run();
    double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    Simulator::Destroy();
    std::printf("%llu %llu %llu %.3f\n", (unsigned long long)g_offered, (unsigned long long)g_sent,
                (unsigned long long)g_received, wall);
    return 0;
}
