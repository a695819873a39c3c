// ns-3 UAN side of bench/ns3_capture.py: the capture-on-a-line scenario of
// uwsimnet_zenoh/experiments/capture.py (docs/acoustic.md, "Capture experiment").
//
// A sink at the origin, N sensors at x = 200, 400, ..., 200 N m (z = 0); UanPhyGen with one FSK mode at
// 1000 bps (22 kHz, 4 kHz band), TxPower 190 dB, UanPhyPerGenDefault (SINR threshold 8 dB),
// UanPhyCalcSinrDefault, RxThreshold 10 dB (defaults); UanPropModelThorp (k = 1.5, delay d / 1500 m/s);
// UanNoiseModelDefault (wind 1 m/s, shipping 0); UanMacAloha (no ACK, no retry, no queue); 37-byte
// payloads (+3 bytes of UanHeaderCommon = 40 bytes = 0.32 s on air); Poisson arrivals of G / (N T) per
// sensor.
//
// usage: ns3_capture N G DURATION SEED
//   -> line 1: "offered sent received wall_s"; line 2: received per sensor (nearest first);
//      line 3: sent per sensor
#include "ns3/core-module.h"
#include "ns3/mobility-module.h"
#include "ns3/network-module.h"
#include "ns3/uan-module.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>

using namespace ns3;

static uint64_t g_offered = 0, g_sent = 0, g_received = 0;
static std::map<Address, uint64_t> g_from;

static bool
SinkRx(Ptr<NetDevice>, Ptr<const Packet>, uint16_t, const Address& from)
{
    ++g_received;
    ++g_from[from];
    return true;
}

struct Source
{
    Ptr<NetDevice> dev;
    Address sink;
    Ptr<ExponentialRandomVariable> gap;
    double stop;
    uint64_t sent = 0;

    void Fire()
    {
        ++g_offered;
        if (dev->Send(Create<Packet>(37), sink, 0))
        {
            ++g_sent;
            ++sent;
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
    Ptr<UanPropModelThorp> prop = CreateObject<UanPropModelThorp>();
    prop->SetAttribute("SpreadCoef", DoubleValue(1.5));
    channel->SetPropagationModel(prop);
    channel->SetNoiseModel(CreateObject<UanNoiseModelDefault>());

    NodeContainer nodes;
    nodes.Create(n + 1);
    Ptr<ListPositionAllocator> pos = CreateObject<ListPositionAllocator>();
    pos->Add(Vector(0, 0, 0));
    for (uint32_t i = 0; i < n; ++i)
    {
        pos->Add(Vector(200.0 * (i + 1), 0, 0));
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
    std::printf("%llu %llu %llu %.3f\n", (unsigned long long)g_offered, (unsigned long long)g_sent,
                (unsigned long long)g_received, wall);
    for (uint32_t i = 0; i < n; ++i)
    {
        std::printf("%llu ", (unsigned long long)g_from[devs.Get(i + 1)->GetAddress()]);
    }
    std::printf("\n");
    for (uint32_t i = 0; i < n; ++i)
    {
        std::printf("%llu ", (unsigned long long)sources[i].sent);
    }
    std::printf("\n");
    Simulator::Destroy();
    return 0;
}
